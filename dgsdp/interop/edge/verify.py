"""Check an imported EDGE model against EDGE's own code, on the same weights, inputs and noise.

EDGE's ``model/`` (and ``dataset/``) are imported from a checkout the user gives (never shipped with dgsdp). Its
sampling module imports ``pytorch3d`` and ``p_tqdm`` for rendering only; where they are not installed, stand-ins
that raise when called take their place, and the report says so. The comparisons:

1. the denoiser: EDGE's ``DanceDecoder`` with the music kept and dropped, and its ``guided_forward`` (weight 2),
   against ours (the guided prediction through the sampler, with its once-per-run conditioning);
2. a whole long-form sample of several windows: EDGE's ``long_ddim_sample`` (DDIM-50, eta 1, its guidance ramp
   and half-window overwrite, x0 clipped to [-1, 1]) against dgsdp's ``sampling=edge`` preset, both drawing
   their noise from the same seed of torch's global generator; compared normalised and after unnormalisation
   (EDGE's ``Normalizer.unnormalize``, which clips to [-1, 1] first, against ours).

EDGE's windows are cut from one music sequence of ``stride * (n - 1) + window`` frames, as dgsdp cuts a song.
"""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from dgsdp.errors import ConfigError
from dgsdp.interop.edge.checkpoint import read_edge_checkpoint
from dgsdp.interop.edge.convert import build_model
from dgsdp.interop.edge.weights import EDGE_HEADS, edge_architecture

TOLERANCE = 1e-4
# imported by EDGE's model/diffusion.py, dataset/quaternion.py and vis.py for rendering only
RENDER_ONLY_MODULES = ("p_tqdm", "pytorch3d", "pytorch3d.transforms")
EDGE_PACKAGES = ("model", "dataset", "vis")  # EDGE's top-level names, imported from its checkout


@dataclass
class VerifyResult:
    denoiser_max_abs_diff: float
    max_abs_diff: float
    details: dict[str, float] = field(default_factory=dict)
    stand_ins: list[str] = field(default_factory=list)

    def passed(self, tolerance: float = TOLERANCE) -> bool:
        return self.max_abs_diff <= tolerance and self.denoiser_max_abs_diff <= tolerance


class _StandIn(types.ModuleType):
    """A module whose every attribute is a function that raises: for imports EDGE's sampling never calls."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)

        def missing(*args: Any, **kwargs: Any) -> Any:
            raise RuntimeError(f"{self.__name__}.{name} is not installed; dgsdp's verify put a stand-in here")

        return missing


def _import_edge_classes(root: Path) -> dict[str, Any]:
    """EDGE's classes, imported from the checkout ``root`` (already first on sys.path); one clear error when a file,
    a class or one of EDGE's own dependencies is missing."""
    try:
        return {
            "DanceDecoder": importlib.import_module("model.model").DanceDecoder,
            "GaussianDiffusion": importlib.import_module("model.diffusion").GaussianDiffusion,
            "Normalizer": importlib.import_module("dataset.preprocess").Normalizer,
            "MinMaxScaler": importlib.import_module("dataset.scaler").MinMaxScaler,
            "SMPLSkeleton": importlib.import_module("vis").SMPLSkeleton,  # the FK of its training loss
            "Adan": importlib.import_module("model.adan").Adan,  # its optimiser
        }
    except ModuleNotFoundError as e:  # one of EDGE's own dependencies (einops, ...), not dgsdp's
        top = (e.name or "").split(".")[0]
        if top in ("", *EDGE_PACKAGES):
            raise ConfigError(f"{root} is not a complete checkout of EDGE: {e}") from e
        raise ConfigError(
            f"EDGE's code in {root} needs the module {e.name!r}, which is not installed: it is one of EDGE's own "
            f"dependencies, not dgsdp's; install it (pip install {top}) and run again"
        ) from e
    except AttributeError as e:  # a file of the checkout without the class: another code than EDGE's
        raise ConfigError(f"{root} is not a checkout of EDGE's code as published (Stanford-TML/EDGE): {e}") from e


@contextmanager
def edge_code(edge_src: str | Path) -> Iterator[tuple[dict[str, Any], list[str]]]:
    """EDGE's classes imported from ``edge_src`` (DanceDecoder, GaussianDiffusion, Normalizer, MinMaxScaler,
    SMPLSkeleton, Adan), with
    stand-ins for the rendering-only modules that are not installed. sys.path and sys.modules are restored."""
    root = Path(edge_src).expanduser().resolve()
    if not (root / "model" / "model.py").is_file() or not (root / "model" / "diffusion.py").is_file():
        raise ConfigError(
            f"{root} is not a checkout of EDGE (no model/model.py and model/diffusion.py); clone Stanford-TML/EDGE "
            "and give its folder with --edge-src"
        )
    saved_modules, saved_path = dict(sys.modules), list(sys.path)
    stand_ins = []
    for name in RENDER_ONLY_MODULES:
        try:
            importlib.import_module(name)
        except ImportError:
            sys.modules[name] = _StandIn(name)
            stand_ins.append(name)
    for name in EDGE_PACKAGES:  # never someone else's module of that name
        for key in [k for k in sys.modules if k == name or k.startswith(name + ".")]:
            del sys.modules[key]
    sys.path.insert(0, str(root))
    try:
        classes = _import_edge_classes(root)
        yield classes, stand_ins
    finally:
        sys.path[:] = saved_path
        for key in set(sys.modules) - set(saved_modules):
            del sys.modules[key]
        sys.modules.update(saved_modules)


def _max_diff(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a.double() - b.double()).abs().max())


def edge_model(
    edge_classes: dict[str, Any],
    seq_len: int,
    width: int,
    ff_dim: int,
    n_layers: int,
    n_heads: int,
    feature_dim: int,
    guidance: float,
    smpl: Any = None,
) -> tuple[torch.nn.Module, torch.nn.Module]:
    """EDGE's own DanceDecoder (random weights, eval mode) and the GaussianDiffusion around it, built as EDGE.py
    builds them (classes from :func:`edge_code`). ``smpl``: the SMPLSkeleton its training loss runs FK with
    (sampling needs none)."""
    decoder = edge_classes["DanceDecoder"](
        nfeats=151,
        seq_len=seq_len,
        latent_dim=width,
        ff_size=ff_dim,
        num_layers=n_layers,
        num_heads=n_heads,
        dropout=0.1,
        cond_feature_dim=feature_dim,
        activation=F.gelu,
    ).eval()
    diffusion = edge_classes["GaussianDiffusion"](
        decoder,
        seq_len,
        151,
        smpl,
        schedule="cosine",
        n_timestep=1000,
        predict_epsilon=False,
        loss_type="l2",
        use_p2=False,
        cond_drop_prob=0.25,
        guidance_weight=guidance,
    ).eval()
    return decoder, diffusion  # fmt: skip


def verify(
    edge_src: str | Path,
    edge_ckpt: str | Path,
    *,
    n_windows: int = 4,
    seed: int = 0,
    weights: str = "ema",
    n_heads: int = EDGE_HEADS,
    log: Any = print,
) -> VerifyResult:
    """Compare the import of ``edge_ckpt`` with EDGE's code from ``edge_src`` (see the module docstring)."""
    from dgsdp.cli.config import compose_config
    from dgsdp.generation.longform import DanceRequest, sample_items
    from dgsdp.sampling import Condition, Guidance, Sampler, SamplingSettings

    if n_windows < 2:
        raise ConfigError("--windows must be at least 2 (EDGE samples one window without its long-form procedure)")
    edge = read_edge_checkpoint(edge_ckpt)
    state = edge.weights(weights)
    arch = edge_architecture(state)
    ours = build_model(edge, weights, n_heads)
    settings = SamplingSettings.from_config(compose_config("generate", ["sampling=edge"]).sampling)
    window, stride = arch.seq_len, arch.seq_len // 2
    details: dict[str, float] = {}
    with edge_code(edge_src) as (edge_classes, stand_ins):
        if stand_ins:
            log(f"not installed, replaced by stand-ins (used by EDGE's rendering only): {', '.join(stand_ins)}")
        theirs, diffusion = edge_model(
            edge_classes, arch.seq_len, arch.d_model, arch.ff_dim, arch.n_layers, n_heads, arch.feature_dim,
            settings.guidance.music,
        )  # fmt: skip
        theirs.load_state_dict(state)
        scaler = edge_classes["MinMaxScaler"]((-1, 1), clip=True)
        for name, value in (("scale_", edge.scaler.scale), ("min_", edge.scaler.min), ("data_min_", edge.scaler.data_min),
                            ("data_max_", edge.scaler.data_max), ("data_range_", edge.scaler.data_range)):  # fmt: skip
            setattr(scaler, name, value.clone())
        normalizer = edge_classes["Normalizer"].__new__(edge_classes["Normalizer"])
        normalizer.scaler = scaler

        gen = torch.Generator().manual_seed(seed)
        x = torch.randn(n_windows, window, 151, generator=gen)
        t = torch.randint(0, 1000, (n_windows,), generator=gen)
        music = torch.randn(stride * (n_windows - 1) + window, arch.feature_dim, generator=gen)
        cond = torch.stack([music[i * stride : i * stride + window] for i in range(n_windows)])
        denoiser = ours.ema.module
        with torch.no_grad():
            keep = torch.ones(n_windows, dtype=torch.bool)
            details["denoiser_music_kept"] = _max_diff(
                theirs(x, cond, t, cond_drop_prob=0.0), denoiser(x, t, cond, keep_music=keep)
            )
            details["denoiser_music_dropped"] = _max_diff(
                theirs(x, cond, t, cond_drop_prob=1.0), denoiser(x, t, cond, keep_music=~keep)
            )
            w = settings.guidance.music
            guided = Sampler(denoiser, ours.diffusion, style_guidance=False, clip_x0=False).predict_x0(
                x, t, Condition(music=cond), Guidance(w)
            )
            details["denoiser_guided"] = _max_diff(theirs.guided_forward(x, cond, t, w), guided)
        for name in ("denoiser_music_kept", "denoiser_music_dropped", "denoiser_guided"):
            log(f"{name}: max |EDGE - dgsdp| = {details[name]:.3g}")

        torch.manual_seed(seed)
        with torch.no_grad():
            edge_windows = diffusion.long_ddim_sample((n_windows, window, 151), cond)
            edge_motion = normalizer.unnormalize(edge_windows.clone())
        torch.manual_seed(seed)
        request = DanceRequest(len(music), music=music, seed=None)  # noise from torch's global generator, as EDGE's
        (our_windows,) = sample_items(
            ours.sampler(), ours.normalizer, [request], window=window, stride=stride, method=settings.method,
            steps=settings.steps, eta=settings.eta, guidance=settings.guidance_for(long=True),
            longform=settings.longform, clip_x0=settings.clip_x0, project=settings.project_rotations, windows=True,
        )  # fmt: skip
        our_windows = our_windows[0]
        details["sample_normalised"] = _max_diff(edge_windows, our_windows)
        details["sample_unnormalised"] = _max_diff(edge_motion, ours.normalizer.unnormalize(our_windows))
        log(
            f"long-form sample ({n_windows} windows, DDIM-{settings.steps}, eta {settings.eta:g}, guidance "
            f"{settings.guidance.music:g}): normalised {details['sample_normalised']:.3g}, "
            f"unnormalised {details['sample_unnormalised']:.3g}"
        )
    return VerifyResult(
        denoiser_max_abs_diff=max(details[k] for k in details if k.startswith("denoiser")),
        max_abs_diff=max(details["sample_normalised"], details["sample_unnormalised"]),
        details=details,
        stand_ins=stand_ins,
    )
