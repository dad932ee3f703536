"""Long-form generation: window layout, overlap sharing, stitching against closed forms, editing in long-form."""

import math

import pytest
import torch
from gen_helpers import AUDIO_DIM, random_motion

from dgsdp.editing import build_mask
from dgsdp.generation import WindowLayout, sample_long, share_overlaps, stitch_windows
from dgsdp.generation.longform import DanceRequest, align_facings, fuse_overlaps, overlap_weights, sample_items
from dgsdp.motion import matrix_to_6d, pack_pose, pose_to_joints, unpack_pose
from dgsdp.sampling import Guidance


@pytest.mark.parametrize(
    ("n_frames", "windows", "padded"),
    [(1, 1, 150), (149, 1, 150), (150, 1, 150), (151, 2, 225), (2850, 37, 2850), (2851, 38, 2925)],
)
def test_window_layout(n_frames, windows, padded):
    layout = WindowLayout(n_frames, 150, 75)
    assert (layout.n_windows, layout.padded_frames) == (windows, padded)
    # 150 + 75 (b - 1) >= n_frames > 150 + 75 (b - 2)
    assert layout.padded_frames >= n_frames and (windows == 1 or layout.padded_frames - 75 < n_frames)


def test_share_overlaps_copies_second_half_into_next_first_half():
    x = torch.arange(2 * 3 * 4, dtype=torch.float32).reshape(6, 4, 1)  # 2 samples x 3 windows of 4 frames
    y = share_overlaps(x, n_windows=3, stride=2)
    for s in range(2):
        w = x[3 * s : 3 * s + 3]
        v = y[3 * s : 3 * s + 3]
        assert torch.equal(v[0], w[0])
        assert torch.equal(v[1, :2], w[0, 2:]) and torch.equal(v[1, 2:], w[1, 2:])
        assert torch.equal(v[2, :2], w[1, 2:]) and torch.equal(v[2, 2:], w[2, 2:])


def test_overlap_weights_of_half_overlapping_windows_sum_to_one():
    w = overlap_weights(150, torch.float64)
    torch.testing.assert_close(w[:75] + w[75:], torch.ones(75, dtype=torch.float64))
    assert w.min() > 0 and w.max() <= 1


def test_fuse_overlaps_is_the_weighted_mean_of_the_covering_windows():
    length, stride, n = 6, 3, 3
    x = torch.randn(2 * n, length, 2, dtype=torch.float64)  # 2 samples x 3 windows
    y = fuse_overlaps(x, n_windows=n, stride=stride)
    w = [math.sin(math.pi * (f + 0.5) / length) ** 2 for f in range(length)]
    for s in range(2):
        win = x[n * s : n * s + n]
        out = y[n * s : n * s + n]
        # frame 3 of the timeline: frame 3 of window 0 and frame 0 of window 1
        expected = (w[3] * win[0, 3] + w[0] * win[1, 0]) / (w[3] + w[0])
        torch.testing.assert_close(out[0, 3], expected)
        torch.testing.assert_close(out[1, 0], expected)
        # frames covered by one window keep their values (the first and last half windows)
        torch.testing.assert_close(out[0, :stride], win[0, :stride])
        torch.testing.assert_close(out[2, stride:], win[2, stride:])
        # neighbours agree on their overlap afterwards, and fusing again changes nothing
        torch.testing.assert_close(out[1, :stride], out[0, stride:])
        torch.testing.assert_close(out[2, :stride], out[1, stride:])
    torch.testing.assert_close(fuse_overlaps(y, n, stride), y)


def test_fuse_overlaps_keeps_windows_cut_from_one_motion():
    timeline = torch.randn(150 + 75 * 3, 4)
    layout = WindowLayout(len(timeline), 150, 75)
    windows = torch.stack([timeline[s : s + 150] for s in layout.starts()])
    torch.testing.assert_close(fuse_overlaps(windows, layout.n_windows, 75), windows)


def rot_z(angle: torch.Tensor) -> torch.Tensor:
    c, s = torch.cos(angle), torch.sin(angle)
    zero, one = torch.zeros_like(angle), torch.ones_like(angle)
    return torch.stack([c, -s, zero, s, c, zero, zero, zero, one], -1).reshape(*angle.shape, 3, 3)


def test_stitch_against_closed_forms():
    length, stride = 8, 4
    overlap = length - stride
    # window 0: every joint at 0.2 rad about z, root at (0, 0, 0), contacts 1; window 1: 1.0 rad, root (4, 0, 2)
    a = pack_pose(torch.ones(length, 4), torch.zeros(length, 3), rot_z(torch.full((length, 24), 0.2)))
    b = pack_pose(torch.zeros(length, 4), torch.tensor([4.0, 0, 2]).expand(length, 3),
                  rot_z(torch.full((length, 24), 1.0)))  # fmt: skip
    out = stitch_windows(torch.stack([a, b]), stride)
    assert out.shape == (length + stride, 151)
    w = torch.arange(overlap) / (overlap - 1)  # 0, 1/3, 2/3, 1
    ov = out[stride:length]
    torch.testing.assert_close(ov[:, 4], 4 * w)
    torch.testing.assert_close(ov[:, 6], 2 * w)
    # slerp between rotations about one axis: the angle moves linearly
    expected = matrix_to_6d(rot_z(0.2 + 0.8 * w)[:, None].expand(overlap, 24, 3, 3)).reshape(overlap, 144)
    torch.testing.assert_close(ov[:, 7:], expected, atol=1e-6, rtol=0)
    assert ov[:, 0].tolist() == [1, 1, 0, 0]  # contacts from the window with the larger weight
    assert torch.equal(out[:stride], a[:stride]) and torch.equal(out[length:], b[overlap:])


def test_longform_lengths_and_window_consistency(tiny_model):
    style = torch.eye(10)[3]
    for n in (40, 150, 151, 2850 + 7):  # short, one window, two windows, a 95 s song and a bit
        out = sample_long(tiny_model.sampler(), tiny_model.normalizer, n, music=torch.randn(n, AUDIO_DIM),
                          style=style, steps=2, generator=torch.Generator().manual_seed(0))  # fmt: skip
        assert out.shape == (1, n, 151) and torch.isfinite(out).all()


def test_per_frame_style_and_samples(tiny_model):
    n = 300
    style = torch.eye(10)[torch.arange(n) * 10 // n]  # (T, 10): a genre per 30 frames
    out = sample_long(tiny_model.sampler(), tiny_model.normalizer, n, music=torch.randn(n, AUDIO_DIM),
                      style=style, num_samples=2, steps=2, guidance=Guidance(2.0, 1.0, ramp_fraction=0.5),
                      chunk_size=3, generator=torch.Generator().manual_seed(0))  # fmt: skip
    assert out.shape == (2, n, 151)
    assert (out[0] - out[1]).abs().max() > 1e-3


def sixd_error(motion: torch.Tensor) -> torch.Tensor:
    """Largest departure of each joint's 6D rotations in (..., 151) motions from two orthonormal columns, (24,)."""
    six = motion[..., 7:].reshape(-1, 24, 6)
    a, b = six[..., :3], six[..., 3:]
    return torch.stack([(a.norm(dim=-1) - 1).abs(), (b.norm(dim=-1) - 1).abs(), (a * b).sum(-1).abs()]).amax((0, 1))


@pytest.mark.parametrize("method", ["ddim", "dpmpp_2m"])
@pytest.mark.parametrize("n_frames", [150, 300])  # one window; long-form (fused)
def test_projected_sampling_gives_valid_rotations(tiny_model, method, n_frames):
    """``project`` makes the 6D rotations of every x0 prediction orthonormal (the root's, or all joints'); the
    random-init model's own are not, and the sampled windows are."""
    music = torch.randn(n_frames, AUDIO_DIM)

    def error(project: str) -> torch.Tensor:
        (w,) = sample_items(
            tiny_model.sampler(), tiny_model.normalizer, [DanceRequest(n_frames, music=music, seed=0)],
            method=method, steps=4, project=project, windows=True,
        )  # fmt: skip
        return sixd_error(tiny_model.normalizer.unnormalize(w))

    unprojected, root, every = error("none"), error("root"), error("all")
    assert (unprojected > 0.1).all()
    assert root[0] < 1e-4 and (root[1:] > 0.1).all()
    assert (every < 1e-4).all()
    with pytest.raises(ValueError, match="rotation projection"):
        error("yes")


TASK_OPTIONS = {
    "seed_motion": {"seed_frames": 30},
    "inbetween": {"seed_frames": 20, "end_frames": 20},
    "inpaint": {"inpaint_fraction": 0.7},
    "upper_body": {},
    "lower_body": {},
    "joints": {"joints": ["left_wrist", "right_elbow", "head"]},
    "keyframes": {"keyframe_seconds": [0.5, 3.0], "keyframes": [-1]},
}


@pytest.mark.parametrize("task", sorted(TASK_OPTIONS))
@pytest.mark.parametrize("n_frames", [100, 240])  # one cropped window; long-form over 3 windows
def test_masked_regions_are_kept_and_the_rest_is_sampled(tiny_model, task, n_frames):
    known = random_motion(400, seed=0)[:n_frames]  # inside the range the normaliser was fitted on
    mask = build_mask(task, n_frames, generator=torch.Generator().manual_seed(1), **TASK_OPTIONS[task])
    music = torch.randn(n_frames, AUDIO_DIM)
    outs = [
        sample_long(
            tiny_model.sampler(),
            tiny_model.normalizer,
            n_frames,
            music=music,
            style=torch.eye(10)[0],
            mask=mask,
            known=known,
            steps=3,
            guidance=Guidance(2.0, 1.0, edit_cap_below_t=100),
            generator=torch.Generator().manual_seed(seed),
        )[0]  # fmt: skip
        for seed in (0, 1)
    ]
    given = mask.bool()
    # normalisation round-off: normalise/unnormalise maps [min, max] to [-1, 1] and back in float32
    scale = (tiny_model.normalizer.data_max - tiny_model.normalizer.data_min).abs().max().item()
    for out in outs:
        assert out.shape == (n_frames, 151)
        torch.testing.assert_close(out[given], known[given], atol=1e-6 * max(scale, 1), rtol=1e-5)
    diff = (outs[0] - outs[1]).abs()[~given]
    assert diff.numel() > 0 and diff.max() > 1e-2
    assert not math.isclose(float(diff.mean()), 0.0)


def test_stitch_keeps_values_the_windows_agree_on():
    # windows cut from one valid motion agree on their overlaps: stitching must give that motion back
    motion = random_motion(300, seed=3)
    windows = torch.stack([motion[s : s + 150] for s in (0, 75, 150)])
    torch.testing.assert_close(stitch_windows(windows, 75), motion, atol=2e-6, rtol=0)


def turned_about_z(motion: torch.Tensor, angle: float, shift: tuple[float, float]) -> torch.Tensor:
    """The same dance turned by ``angle`` about the vertical through the origin, then moved ``shift`` (x, y)."""
    parts = unpack_pose(motion)
    turn = rot_z(torch.tensor(angle, dtype=motion.dtype))
    rotmats = parts.rotmats.clone()
    rotmats[:, 0] = turn @ rotmats[:, 0]
    trans = parts.root_trans @ turn.T + torch.tensor([*shift, 0.0], dtype=motion.dtype)
    return pack_pose(parts.contacts, trans, rotmats)


def test_align_facings_undoes_a_turn_of_each_window():
    """Windows cut from one dance, each but the first turned and moved by its own amount, are turned back onto
    the dance (the same joints, not only the same facing); a window that already agrees is left as it is."""
    motion = random_motion(300, seed=4).double()
    starts, window, stride = (0, 75, 150), 150, 75
    cut = torch.stack([motion[s : s + window] for s in starts])
    turned = torch.stack([cut[0]] + [turned_about_z(w, a, sh) for w, a, sh in
                                     zip(cut[1:], (2.5, -1.2), ((3.0, -1.0), (-0.5, 2.0)))])  # fmt: skip
    assert (pose_to_joints(turned[1]) - pose_to_joints(cut[1])).norm(dim=-1).max() > 1.0
    aligned = align_facings(turned, len(starts), stride)
    torch.testing.assert_close(pose_to_joints(aligned), pose_to_joints(cut), atol=1e-9, rtol=0)
    torch.testing.assert_close(aligned[..., 7:], cut[..., 7:], atol=1e-6, rtol=0)  # float32 rotations re-encoded
    torch.testing.assert_close(align_facings(cut, len(starts), stride), cut, atol=1e-12, rtol=0)
    torch.testing.assert_close(align_facings(turned[:1], 1, stride), turned[:1])


def test_align_facings_agrees_with_the_mean_turn_of_the_overlap():
    """Where the later window's facing differs from the earlier one's by a different angle on each shared frame
    (the body upright), the turn is their circular mean, and the root's height and the joints below it are not
    moved."""
    window, stride = 6, 3
    upright = torch.tensor([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=torch.float64)  # body z (forward) -> world -y

    def dance(angles: torch.Tensor, height: float) -> torch.Tensor:
        rotmats = rot_z(angles)[:, None].expand(window, 24, 3, 3).clone()
        rotmats[:, 0] = rot_z(angles) @ upright
        return pack_pose(torch.zeros(window, 4), torch.tensor([0.0, 0.0, height]).expand(window, 3), rotmats)

    def heading(x: torch.Tensor) -> torch.Tensor:
        return torch.atan2(x[:, 7 + 5], x[:, 7 + 2])

    angles = torch.tensor([0.0, 0.1, 0.2, 0.3, 0.4, 0.5], dtype=torch.float64)
    offsets = torch.tensor([1.0, 1.2, 1.4], dtype=torch.float64)  # b lags a by these on the 3 shared frames
    b_angles = torch.cat([angles[stride:] - offsets, angles[stride:] + 0.1 - offsets[-1]])
    a, b = dance(angles, 0.0), dance(b_angles, 0.9)
    out = align_facings(torch.stack([a, b]), 2, stride)
    turn = torch.remainder(heading(out[1]) - heading(b) + math.pi, 2 * math.pi) - math.pi
    torch.testing.assert_close(turn, torch.full((window,), 1.2, dtype=torch.float64), atol=1e-9, rtol=0)
    torch.testing.assert_close(out[1, :, 6], b[:, 6])
    torch.testing.assert_close(out[1, :, 13:], b[:, 13:])  # the other joints' rotations are untouched
    torch.testing.assert_close(out[0], a)


def test_align_facing_in_sampling_turns_unedited_dances_only(tiny_model):
    """With ``align_facing`` the fused windows of an unedited dance are turned before each fusion (the random-init
    model's windows face every way, so its dance changes), while an edited dance in the same batch is sampled as
    without it (its given root decides where it faces)."""
    n = 300
    known = random_motion(400, seed=0)[:n]
    mask = build_mask("joints", n, joints=["left_wrist", "head"])  # the root is not given: alignment would turn it
    music = torch.randn(n, AUDIO_DIM)

    def run(align: bool) -> list[torch.Tensor]:
        requests = [DanceRequest(n, music=music, seed=0), DanceRequest(n, music=music, mask=mask, known=known, seed=1)]
        return sample_items(tiny_model.sampler(), tiny_model.normalizer, requests, method="dpmpp_2m", steps=3,
                            project="root", align_facing=align)  # fmt: skip

    (plain, edited_plain), (turned, edited) = run(False), run(True)
    assert torch.isfinite(turned).all() and (turned - plain).abs().max() > 1e-2
    # every channel of the edited dance, not only the given ones (which are put back at the end anyway)
    torch.testing.assert_close(edited, edited_plain, atol=1e-6, rtol=0)
