"""dance_loss terms against hand computations on tiny motions, each term isolated by its weight."""

import math

import numpy as np
import pytest
import torch

from dgsdp.diffusion import LossWeights, dance_loss
from dgsdp.motion import MinMaxNormalizer, pack_pose
from dgsdp.motion.skeleton import PARENTS, REST_OFFSETS_M

B, T = 2, 5
FEET = (7, 8, 10, 11)  # left/right ankle, left/right toe: the joints whose contacts channels 0-3 hold


def only(name: str, weight: float = 1.0, **extra) -> LossWeights:
    weights = {"simple": 0.0, "velocity": 0.0, "fk": 0.0, "foot": 0.0, name: weight}
    return LossWeights(**weights, **extra)


@pytest.fixture(scope="module")
def normalizer() -> MinMaxNormalizer:
    """Contacts in [0, 1], everything else in [-3, 3]: normalised = (x - min) / (max - min) * 2 - 1."""
    norm = MinMaxNormalizer(151)
    norm.data_min.fill_(-3.0)
    norm.data_max.fill_(3.0)
    norm.data_min[:4], norm.data_max[:4] = 0.0, 1.0
    return norm


def motion(trans: np.ndarray, root_rot: np.ndarray | None = None, contacts: np.ndarray | None = None) -> torch.Tensor:
    """Unnormalised (B, T, 151): rest pose (identity joint rotations) except the root rotation, given translation."""
    rot = np.broadcast_to(np.eye(3), (B, T, 24, 3, 3)).copy()
    if root_rot is not None:
        rot[:, :, 0] = root_rot
    contacts = np.zeros((B, T, 4)) if contacts is None else contacts
    return pack_pose(torch.from_numpy(contacts), torch.from_numpy(trans), torch.from_numpy(rot)).float()


def rest_joints() -> np.ndarray:
    """Joint positions of the rest pose relative to the root (24, 3): sums of rest offsets along the chain."""
    pos = np.zeros((24, 3))
    for j in range(1, 24):
        pos[j] = pos[PARENTS[j]] + np.array(REST_OFFSETS_M[j])
    return pos


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_simple_term_is_mse_over_all_channels(normalizer):
    g = torch.Generator().manual_seed(0)
    pred, x0 = torch.rand(B, T, 151, generator=g) * 2 - 1, torch.rand(B, T, 151, generator=g) * 2 - 1
    out = dance_loss(pred, x0, normalizer, only("simple", 1.7))
    expected = np.mean((pred.double().numpy() - x0.double().numpy()) ** 2)
    assert out["simple"].item() == pytest.approx(expected, rel=1e-6)
    assert out["loss"].item() == pytest.approx(1.7 * expected, rel=1e-6)
    assert "fk" not in out and "foot" not in out  # zero weight: the FK terms are not computed


def test_velocity_term_uses_motion_channels_only(normalizer):
    g = torch.Generator().manual_seed(1)
    pred, x0 = torch.rand(B, T, 151, generator=g) * 2 - 1, torch.rand(B, T, 151, generator=g) * 2 - 1
    p, x = pred.double().numpy(), x0.double().numpy()
    dp, dx = np.diff(p[:, :, 4:], axis=1), np.diff(x[:, :, 4:], axis=1)  # (B, T-1, 147)
    expected = np.sum((dp - dx) ** 2) / (B * (T - 1) * 147)
    out = dance_loss(pred, x0, normalizer, only("velocity", 2.5))
    assert out["velocity"].item() == pytest.approx(expected, rel=1e-5)
    assert out["loss"].item() == pytest.approx(2.5 * expected, rel=1e-5)
    # contacts do not move: a prediction that differs from x0 only in the contact channels has zero velocity loss
    only_contacts = x0.clone()
    only_contacts[..., :4] = torch.rand(B, T, 4, generator=g)
    out = dance_loss(only_contacts, x0, normalizer, only("velocity"))
    assert out["velocity"].item() == 0.0 and out["simple"].item() > 0


def test_fk_term_translation_shift(normalizer):
    """Shifting the root by d moves every joint by d: FK MSE = mean over frames of |d|^2 / 3."""
    rng = np.random.default_rng(2)
    trans = rng.uniform(-0.5, 0.5, (B, T, 3))
    shift = rng.uniform(-0.3, 0.3, (B, T, 3))
    pred = normalizer.normalize(motion(trans + shift))
    x0 = normalizer.normalize(motion(trans))
    out = dance_loss(pred, x0, normalizer, only("fk", 0.5))
    expected = np.mean(np.sum(shift**2, axis=-1)) / 3
    assert out["fk"].item() == pytest.approx(expected, rel=1e-4)
    assert out["loss"].item() == pytest.approx(0.5 * expected, rel=1e-4)


def test_fk_term_root_rotation(normalizer):
    """Rotating the root by R moves joint j (rest position p_j from the root) by (R - I) p_j."""
    trans = np.zeros((B, T, 3))
    angles = np.linspace(0.1, 1.2, B * T).reshape(B, T)
    rots = np.stack([[rot_z(a) for a in row] for row in angles])  # (B, T, 3, 3)
    pred = normalizer.normalize(motion(trans, root_rot=rots))
    x0 = normalizer.normalize(motion(trans))
    p = rest_joints()
    diff = np.einsum("btij,kj->btki", rots - np.eye(3), p)  # (B, T, 24, 3)
    expected = np.mean(diff**2)
    out = dance_loss(pred, x0, normalizer, only("fk"))
    assert expected > 1e-3
    assert out["fk"].item() == pytest.approx(expected, rel=1e-4)


def test_foot_term_counts_predicted_contacts_above_threshold(normalizer):
    """Rest pose moving with the root: every foot joint's velocity is the root's. The term is the mean over
    (B, T-1, 4 feet, 3) of the squared velocity where the predicted contact (at the earlier frame) is on."""
    rng = np.random.default_rng(3)
    trans = np.cumsum(rng.uniform(-0.05, 0.05, (B, T, 3)), axis=1)
    contacts = rng.choice([0.0, 0.9, 0.97, 1.0], size=(B, T, 4))
    pred = normalizer.normalize(motion(trans, contacts=contacts))
    x0 = normalizer.normalize(motion(np.zeros((B, T, 3))))  # the target does not enter the foot term
    vel2 = np.sum(np.diff(trans, axis=1) ** 2, axis=-1)  # (B, T-1)
    for threshold in (0.95, 0.5):
        on = (contacts[:, :-1] > threshold).astype(float)  # (B, T-1, 4)
        expected = np.sum(on * vel2[..., None]) / (B * (T - 1) * 4 * 3)
        out = dance_loss(pred, x0, normalizer, only("foot", 3.0, contact_threshold=threshold))
        assert expected > 0
        assert out["foot"].item() == pytest.approx(expected, rel=1e-4)
        assert out["loss"].item() == pytest.approx(3.0 * expected, rel=1e-4)
    # no predicted contact: no foot loss, however the feet move
    pred_free = normalizer.normalize(motion(trans))
    assert dance_loss(pred_free, x0, normalizer, only("foot"))["foot"].item() == 0.0


def test_default_weights_sum_the_four_terms(normalizer):
    rng = np.random.default_rng(4)
    trans = np.cumsum(rng.uniform(-0.05, 0.05, (B, T, 3)), axis=1)
    contacts = rng.choice([0.0, 1.0], size=(B, T, 4))
    pred = normalizer.normalize(motion(trans + 0.1, contacts=contacts))
    x0 = normalizer.normalize(motion(trans))
    p, x = pred.double().numpy(), x0.double().numpy()
    simple = np.mean((p - x) ** 2)
    velocity = np.mean((np.diff(p[:, :, 4:], axis=1) - np.diff(x[:, :, 4:], axis=1)) ** 2)
    fk = 0.1**2  # every joint shifted by (0.1, 0.1, 0.1)
    vel2 = np.sum(np.diff(trans, axis=1) ** 2, axis=-1)
    foot = np.sum((contacts[:, :-1] > 0.95) * vel2[..., None]) / (B * (T - 1) * 12)
    w = LossWeights()
    out = dance_loss(pred, x0, normalizer, w)
    for name, value in {"simple": simple, "velocity": velocity, "fk": fk, "foot": foot}.items():
        assert out[name].item() == pytest.approx(value, rel=1e-4, abs=1e-9), name
    total = w.simple * simple + w.velocity * velocity + w.fk * fk + w.foot * foot
    assert out["loss"].item() == pytest.approx(total, rel=1e-4)


def test_loss_is_differentiable_in_the_prediction(normalizer):
    rng = np.random.default_rng(5)
    trans = np.cumsum(rng.uniform(-0.05, 0.05, (B, T, 3)), axis=1)
    pred = normalizer.normalize(motion(trans + 0.05, contacts=np.ones((B, T, 4)))).requires_grad_(True)
    x0 = normalizer.normalize(motion(trans))
    dance_loss(pred, x0, normalizer, LossWeights())["loss"].backward()
    assert torch.isfinite(pred.grad).all() and pred.grad[..., 4:7].abs().sum() > 0


def test_pause_term_weights_the_velocity_error_by_the_true_motion_stillness():
    """Three steps of the true motion: still (weight 1), at the window's mean speed and at twice it (weight 0)."""
    torch.manual_seed(7)
    x0 = torch.zeros(1, 4, 151)
    # true steps of the 147 motion channels: 0 (still), 0.3, 0.6 -> speeds 0, 0.3, 0.6; window mean 0.3
    x0[:, 2, 4:] = 0.3
    x0[:, 3, 4:] = 0.9
    pred = x0 + 0.1 * torch.randn(1, 4, 151)
    err = ((pred[:, 1:, 4:] - pred[:, :-1, 4:]) - (x0[:, 1:, 4:] - x0[:, :-1, 4:])).square().mean(dim=-1)  # (1, 3)
    stillness = torch.tensor([1.0, 0.0, 0.0])  # relu(1 - speed / 0.3)
    expected = (stillness * err).sum() / 3
    terms = dance_loss(pred, x0, None, only("pause"))
    assert torch.allclose(terms["pause"], expected, atol=1e-7)
    assert torch.allclose(terms["loss"], expected, atol=1e-7)
    assert "pause" not in dance_loss(pred, x0, None, only("velocity"))  # off (weight 0): not computed


def test_root_term_is_the_velocity_error_of_the_root_translation_alone():
    torch.manual_seed(8)
    x0, pred = torch.randn(2, 6, 151), torch.randn(2, 6, 151)
    root = slice(4, 7)  # after the 4 contact channels
    expected = (((pred[:, 1:, root] - pred[:, :-1, root]) - (x0[:, 1:, root] - x0[:, :-1, root])) ** 2).mean()
    terms = dance_loss(pred, x0, None, only("root"))
    assert torch.allclose(terms["root"], expected, atol=1e-7)
    assert torch.allclose(terms["loss"], expected, atol=1e-7)
    moved = pred.clone()
    moved[..., 7:] += torch.randn(2, 6, 144)  # the rotations do not enter it
    assert torch.allclose(dance_loss(moved, x0, None, only("root"))["root"], expected, atol=1e-7)
    assert "root" not in dance_loss(pred, x0, None, only("velocity"))  # off (weight 0): not computed


def test_fk_and_foot_terms_equal_the_skeletons_own_fk_after_a_call_under_inference_mode(normalizer):
    """The rest offsets and foot joints are made into tensors once per device and kept (no copy from the host per
    step): a first call under inference mode (a validation step) must not leave tensors that a training step cannot
    save for its backward pass, and the terms equal those of PoseParts.joints() and list indexing."""
    from dgsdp.motion import unpack_pose

    rng = np.random.default_rng(11)
    trans = np.cumsum(rng.uniform(-0.05, 0.05, (B, T, 3)), axis=1)
    contacts = (rng.uniform(size=(B, T, 4)) > 0.3).astype(float)
    pred = normalizer.normalize(motion(trans + 0.05, rot_z(0.3), contacts))
    x0 = normalizer.normalize(motion(trans))
    weights = LossWeights(simple=0.0, velocity=0.0)
    with torch.inference_mode():
        dance_loss(pred.double(), x0.double(), normalizer.double(), weights)  # float64: a dtype of its own
        dance_loss(pred, x0, normalizer, weights)
    grad_pred = pred.clone().requires_grad_(True)
    terms = dance_loss(grad_pred, x0, normalizer, weights)
    terms["loss"].backward()
    assert torch.isfinite(grad_pred.grad).all()
    pred_joints = unpack_pose(normalizer.unnormalize(pred)).joints()
    fk = torch.nn.functional.mse_loss(pred_joints, unpack_pose(normalizer.unnormalize(x0)).joints())
    assert torch.equal(terms["fk"].detach(), fk)
    on = (unpack_pose(normalizer.unnormalize(pred)).contacts > weights.contact_threshold).float()
    feet = pred_joints[:, :, list(FEET)]
    foot_vel = (feet[:, 1:] - feet[:, :-1]) * on[:, :-1, :, None]
    assert torch.equal(terms["foot"].detach(), foot_vel.square().mean())
