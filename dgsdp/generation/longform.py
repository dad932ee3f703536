"""Long-form generation: a dance of any length from a batch of overlapping windows sampled together.

The motion is cut into consecutive windows of ``window`` frames (5 s) starting ``stride`` frames (2.5 s) apart,
padded at the end so that the windows cover it. All windows are denoised in one batch, kept in agreement on their
overlaps: the initial noise of an overlap is the same in both windows, and every x0 prediction is fused, each
frame becoming the weighted mean of the predictions of the windows that cover it (weights falling towards each
window's ends, :func:`fuse_overlaps`). The ODE solvers' updates are linear in the state and x0, so the windows
then agree exactly at every step; samplers that draw fresh noise copy the earlier window's overlap into the next
window after each step. Neighbouring windows therefore end on the same motion and no window edge is a hard cut.
EDGE (``longform="edge"``, the ``sampling=edge`` preset) instead starts every window from its own noise,
overwrites each window's first half with its neighbour's state after every step but the last, never fuses the x0
predictions, and cross-fades the final windows: with the quickstart model on real songs that left joint speed around the window
boundaries up to 1.43x the dance's average (seam ratio, docs/notes/2026-11-23-real-songs.md); fused windows give 0.42-0.59x (below
1 because where a weak model's neighbouring windows disagree, the blend between them adds motion away from the
boundaries). The stitched result is cropped to the requested length. A motion shorter than one window is sampled
as one padded window and cropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from dgsdp.motion import (
    SMPL24,
    MinMaxNormalizer,
    Skeleton,
    matrix_slerp,
    matrix_to_6d,
    project_rotations,
    sixd_to_matrix,
)
from dgsdp.motion.representation import CONTACT_CHANNELS, ROOT_CHANNELS
from dgsdp.sampling import Condition, Guidance, Noise, Sampler
from dgsdp.sampling.settings import LONGFORM_MODES, ROTATION_PROJECTION_CHOICES


@dataclass(frozen=True)
class WindowLayout:
    """Where the windows of a long motion lie: ``n_windows`` of ``window`` frames, ``stride`` apart."""

    n_frames: int
    window: int
    stride: int

    def __post_init__(self) -> None:
        if self.n_frames <= 0:
            raise ValueError(f"a motion needs at least one frame, got {self.n_frames}")
        if not 0 < self.stride <= self.window:
            raise ValueError(f"the stride must lie in 1..window ({self.window}), got {self.stride}")

    @property
    def n_windows(self) -> int:
        return max(1, math.ceil((self.n_frames - self.window) / self.stride) + 1)

    @property
    def overlap(self) -> int:
        return self.window - self.stride

    @property
    def padded_frames(self) -> int:
        """Frames the windows cover: ``window + stride * (n_windows - 1)`` (>= n_frames)."""
        return self.window + self.stride * (self.n_windows - 1)

    def starts(self) -> list[int]:
        return [i * self.stride for i in range(self.n_windows)]


def pad_frames(x: torch.Tensor, n_frames: int, value: float | None = None) -> torch.Tensor:
    """Pad (T, ...) to ``n_frames`` rows by repeating the last row (``value=None``) or with a constant."""
    t = x.shape[0]
    if t >= n_frames:
        return x[:n_frames]
    if value is None:
        pad = x[-1:].expand(n_frames - t, *x.shape[1:])
    else:
        pad = torch.full((n_frames - t, *x.shape[1:]), value, dtype=x.dtype, device=x.device)
    return torch.cat([x, pad], dim=0)


def cut_windows(x: torch.Tensor, layout: WindowLayout) -> torch.Tensor:
    """(layout.padded_frames, ...) -> (n_windows, window, ...)."""
    return torch.stack([x[s : s + layout.window] for s in layout.starts()])


def share_overlaps(x: torch.Tensor, n_windows: int, stride: int) -> torch.Tensor:
    """Overwrite the first frames of window i+1 with the last frames of window i.

    x: (S * n_windows, window, C), the windows of S samples one after the other. Returns a new tensor.
    """
    if n_windows < 2:
        return x
    s = x.shape[0] // n_windows
    w = x.reshape(s, n_windows, *x.shape[1:]).clone()
    overlap = x.shape[1] - stride
    w[:, 1:, :overlap] = w[:, :-1, stride:]
    return w.reshape(x.shape)


def overlap_weights(window: int, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """Per-frame weights (window,) of a window in :func:`fuse_overlaps`: sin^2(pi (f + 0.5) / window), rising
    from the window's ends to 1 in its middle. Two windows half a window apart sum to exactly 1 on every frame."""
    f = torch.arange(window, dtype=torch.float64, device=device)
    return torch.sin(math.pi * (f + 0.5) / window).pow(2).to(dtype)


def fuse_overlaps(x: torch.Tensor, n_windows: int, stride: int) -> torch.Tensor:
    """Make overlapping windows agree: every frame becomes the weighted mean of the windows that cover it.

    x: (S * n_windows, window, C), the windows of S samples one after the other. The weights
    (:func:`overlap_weights`) fall towards each window's ends, so no window's edge is a hard cut in the fused
    motion (a frame covered by one window keeps its value). Returns a new tensor.
    """
    if n_windows < 2:
        return x
    s, length = x.shape[0] // n_windows, x.shape[1]
    w = x.reshape(s, n_windows, length, -1)
    weight = overlap_weights(length, x.dtype, x.device)
    total = length + stride * (n_windows - 1)
    acc = x.new_zeros(s, total, w.shape[-1])
    norm = x.new_zeros(total)
    for i in range(n_windows):
        acc[:, i * stride : i * stride + length] += weight[:, None] * w[:, i]
        norm[i * stride : i * stride + length] += weight
    fused = acc / norm[:, None]
    return torch.stack([fused[:, i * stride : i * stride + length] for i in range(n_windows)], dim=1).reshape(x.shape)


def align_facings(x: torch.Tensor, n_windows: int, stride: int) -> torch.Tensor:
    """Turn each window about the vertical axis, and shift it over the floor, to agree with the window before it.

    x: unnormalised pose vectors (S * n_windows, window, D) of any skeleton (D = 7 + 6 J), the windows of S samples
    one after the other. Window i (i >= 1) is turned by the angle that best maps its body's facing on the frames it
    shares with window i - 1 (already turned) onto that window's: the argument of the sum over those frames of
    f_prev * conj(f_i), f the horizontal part of the body's forward axis as a complex number, so frames where the
    body leans far get less say. Its root translation is turned by the same angle about the vertical axis and then
    shifted so that its mean over the shared frames equals the earlier window's. Only the root rotation and the
    root translation's horizontal part change, and linearly in the stored 6D rows, so the turn is exact for any 6D
    vector. A dance is the same dance turned about the vertical, so each window keeps its own motion; fusing then
    averages windows that face the same way instead of two facings up to 180 degrees apart (which the fusion's
    weights sweep from one to the other within a few frames). Returns a new tensor.
    """
    overlap = x.shape[1] - stride
    if n_windows < 2 or overlap <= 0:
        return x
    s = x.shape[0] // n_windows
    w = x.reshape(s, n_windows, *x.shape[1:]).clone()
    rot = slice(ROOT_CHANNELS.stop, ROOT_CHANNELS.stop + 6)  # the root's two stored rows r0, r1 (r2 is implied)
    xy = slice(ROOT_CHANNELS.start, ROOT_CHANNELS.start + 2)
    for i in range(1, n_windows):
        prev, cur = w[:, i - 1, stride:], w[:, i, :overlap]
        # The body's forward axis (column 2 of the root rotation): x = r0[2], y = r1[2].
        f_prev = torch.complex(prev[..., rot][..., 2], prev[..., rot][..., 5])
        f_cur = torch.complex(cur[..., rot][..., 2], cur[..., rot][..., 5])
        angle = torch.angle((f_prev * f_cur.conj()).sum(dim=1))[:, None, None]  # 0 where no frame has a facing
        c, sn = torch.cos(angle), torch.sin(angle)
        r0, r1 = w[:, i, :, rot][..., :3], w[:, i, :, rot][..., 3:]
        w[:, i, :, rot] = torch.cat((c * r0 - sn * r1, sn * r0 + c * r1), dim=-1)
        px, py = w[:, i, :, xy][..., :1], w[:, i, :, xy][..., 1:]
        turned = torch.cat((c * px - sn * py, sn * px + c * py), dim=-1)
        shift = (prev[..., xy] - turned[:, :overlap]).mean(dim=1, keepdim=True)
        w[:, i, :, xy] = turned + shift
    return w.reshape(x.shape)


def stitch_windows(windows: torch.Tensor, stride: int) -> torch.Tensor:
    """Stitch unnormalised windows (n, L, D) of pose vectors (any skeleton's: D = 7 + 6 J) into one motion
    (L + stride * (n - 1), D).

    Over each overlap the ramp weight w runs linearly from 0 (earlier window) to 1 (later window): root
    translation is (1 - w) a + w b, joint rotations are slerped with weight w, contacts come from the earlier
    window where w < 0.5 and from the later one elsewhere. Frames outside overlaps are kept as they are.
    """
    n, length, dim = windows.shape
    n_joints = (dim - ROOT_CHANNELS.stop) // 6
    rotations = slice(ROOT_CHANNELS.stop, dim)
    overlap = length - stride
    out = windows[0].clone()
    if overlap > 0:
        ramp = torch.linspace(0, 1, overlap, dtype=windows.dtype, device=windows.device)
    for i in range(1, n):
        nxt = windows[i]
        start = i * stride
        if overlap > 0:
            a, b = out[start:], nxt[:overlap]
            mixed = a.clone()
            w = ramp[:, None]
            mixed[:, ROOT_CHANNELS] = (1 - w) * a[:, ROOT_CHANNELS] + w * b[:, ROOT_CHANNELS]
            mixed[:, CONTACT_CHANNELS] = torch.where(w < 0.5, a[:, CONTACT_CHANNELS], b[:, CONTACT_CHANNELS])
            ra = sixd_to_matrix(a[:, rotations].reshape(overlap, n_joints, 6))
            rb = sixd_to_matrix(b[:, rotations].reshape(overlap, n_joints, 6))
            rot = matrix_slerp(ra, rb, ramp[:, None].expand(overlap, n_joints))
            mixed[:, rotations] = matrix_to_6d(rot).reshape(overlap, n_joints * 6)
            # The ends of the ramp are exactly one window: keep its values untouched.
            mixed[0] = a[0]
            mixed[-1] = b[-1]
            out = torch.cat([out[:start], mixed, nxt[overlap:]], dim=0)
        else:
            out = torch.cat([out, nxt], dim=0)
    return out


class ChunkedDenoiser(nn.Module):
    """Runs a denoiser over a large batch in chunks of ``chunk_size`` items, to bound memory.

    ``condition(...)`` conditions the inner denoiser chunk by chunk (when it can, else None) for
    ``forward(x_t, t, cond=...)``.
    """

    def __init__(self, denoiser: nn.Module, chunk_size: int) -> None:
        super().__init__()
        self.denoiser = denoiser
        self.chunk_size = int(chunk_size)

    @property
    def guidance_inputs(self) -> int:
        """The inner denoiser's guidance inputs (a guidance-distilled student's; 0 for other denoisers)."""
        return getattr(self.denoiser, "guidance_inputs", 0)

    def _slices(self, b: int) -> list[slice]:
        if self.chunk_size <= 0 or b <= self.chunk_size:
            return [slice(0, b)]
        return [slice(i, i + self.chunk_size) for i in range(0, b, self.chunk_size)]

    def condition(
        self, music, style, keep_music, keep_style, *, n_frames: int, batch: int, music_rows=None
    ) -> list | None:
        inner = getattr(self.denoiser, "condition", None)
        if inner is None:
            return None

        def part(v: torch.Tensor | None, sl: slice) -> torch.Tensor | None:
            return None if v is None else v[sl]

        return [
            inner(
                music if music_rows is not None else part(music, sl),  # rows named by music_rows: all of it
                part(style, sl),
                part(keep_music, sl),
                part(keep_style, sl),
                n_frames=n_frames,
                batch=len(range(batch)[sl]),
                music_rows=part(music_rows, sl),
            )  # fmt: skip
            for sl in self._slices(batch)
        ]

    def forward(
        self,
        x_t: torch.Tensor,
        t: torch.Tensor,
        music: torch.Tensor | None = None,
        style: torch.Tensor | None = None,
        keep_music: torch.Tensor | None = None,
        keep_style: torch.Tensor | None = None,
        *,
        cond: list | None = None,
        guidance: torch.Tensor | None = None,
        same_step: bool = False,
    ) -> torch.Tensor:
        """The inner denoiser's prediction, chunk by chunk; ``same_step`` (with ``cond``) is passed on (see
        :meth:`~dgsdp.model.denoiser.DanceDenoiser.forward`)."""
        slices = self._slices(x_t.shape[0])
        step = {"same_step": True} if same_step else {}

        def weights(sl: slice) -> dict:
            """A guidance-distilled student's weights of rows ``sl`` (no argument for other denoisers)."""
            return {} if guidance is None else {"guidance": guidance[sl]}

        if cond is not None:
            return torch.cat(
                [
                    self.denoiser(x_t[sl], t[sl], cond=c, **step, **weights(sl))
                    for sl, c in zip(slices, cond, strict=True)
                ]
            )
        if len(slices) == 1:
            return self.denoiser(x_t, t, music, style, keep_music, keep_style, **weights(slice(None)))
        outs = []
        for sl in slices:

            def part(v: torch.Tensor | None, sl: slice = sl) -> torch.Tensor | None:
                return None if v is None else v[sl]

            outs.append(
                self.denoiser(
                    x_t[sl], t[sl], part(music), part(style), part(keep_music), part(keep_style), **weights(sl)
                )
            )
        return torch.cat(outs)


@dataclass
class DanceRequest:
    """One dance to make: ``n_frames`` at 30 FPS, music features (n_frames, Da), per long-form window
    (n_windows, window, Da) or None, style (ds,), per frame
    (n_frames, ds) or None, an optional editing mask with the given motion (both (n_frames, D), unnormalised),
    the number of samples, and where its noise comes from: a seed (or a generator to draw from) of its own, so the
    same request with the same seed gives the same dance, alone or in a batch; None uses the global RNG."""

    n_frames: int
    music: torch.Tensor | None = None
    style: torch.Tensor | None = None
    mask: torch.Tensor | None = None
    known: torch.Tensor | None = None
    num_samples: int = 1
    seed: int | torch.Generator | None = 0

    def generator(self, device: torch.device) -> torch.Generator | None:
        if self.seed is None or isinstance(self.seed, torch.Generator):
            return self.seed
        return torch.Generator(device=device).manual_seed(int(self.seed))


def sample_items(
    sampler: Sampler,
    normalizer: MinMaxNormalizer,
    items: list[DanceRequest],
    *,
    window: int = 150,
    stride: int = 75,
    method: str = "ddim",
    steps: int | None = 50,
    eta: float = 1.0,
    guidance: Guidance | None = None,
    chunk_size: int = 0,
    longform: str = "fuse",
    clip_x0: float | None = None,
    project: str = "none",
    align_facing: bool = False,
    device: torch.device | str = "cpu",
    progress: bool = False,
    windows: bool = False,
    skeleton: Skeleton = SMPL24,
) -> list[torch.Tensor]:
    """Sample several dances of any lengths in one batch: returns one unnormalised (S, n_frames, D) per item, D the
    pose size of the run's ``skeleton`` (SMPL-24: 151).

    Each dance is cut into windows of ``window`` frames ``stride`` apart (one padded window when shorter); all
    windows of all items are denoised together (``chunk_size`` > 0 bounds the denoiser's batch), neighbours of
    the same dance agree on their overlap after every step (``longform``: ``fuse`` or EDGE's ``edge``, see the
    module docstring), and the windows are stitched. The given channels of an edited dance equal its ``known``
    motion. A request with a seed draws its noise from it alone. ``clip_x0`` replaces the run's x0 bound.
    ``project`` (``root`` or ``all``; ``none`` = not) makes those 6D rotations of every x0 prediction valid
    rotations, after the fusion (:func:`~dgsdp.motion.project_rotations`; ``sampling.project_rotations``).
    ``align_facing`` (``fuse`` only) turns each window of an unedited dance to face as its neighbour does on their
    overlap before every fusion (:func:`align_facings`; ``sampling.align_facing``).
    ``windows=True`` returns each item's normalised windows (S, n_windows, window, D) instead, as sampled."""
    if not items:
        return []
    if longform not in LONGFORM_MODES:
        raise ValueError(f"unknown long-form mode {longform!r}; use one of {', '.join(LONGFORM_MODES)}")
    if project not in ROTATION_PROJECTION_CHOICES:
        raise ValueError(
            f"unknown rotation projection {project!r}; use one of {', '.join(ROTATION_PROJECTION_CHOICES)}"
        )
    device = torch.device(device)
    pose_dim = skeleton.pose_dim
    if normalizer.data_min.numel() != pose_dim:
        raise ValueError(
            f"the normaliser has {normalizer.data_min.numel()} channels, {skeleton.name}'s poses {pose_dim}"
        )
    if len({it.music is None for it in items}) > 1 or len({it.style is None for it in items}) > 1:
        raise ValueError("the dances of one batch must all have music (or none) and all have a style (or none)")
    layouts = [WindowLayout(it.n_frames, window, stride) for it in items]
    per_frame_style = any(it.style is not None and it.style.ndim == 2 for it in items)
    any_mask = any(it.mask is not None for it in items)
    music, style, masks, knowns, given, rows = [], [], [], [], [], []
    for it, layout in zip(items, layouts):
        n_win, total = layout.n_windows, layout.padded_frames

        def windows_of(x: torch.Tensor, pad_value: float | None = None, it=it, layout=layout) -> torch.Tensor:
            w = cut_windows(pad_frames(x.to(device), layout.padded_frames, pad_value), layout)
            return w.repeat(it.num_samples, *([1] * (w.ndim - 1)))

        rows.append(it.num_samples * n_win)
        if it.music is not None and it.music.ndim == 3:  # features per window already (EDGE's procedure)
            if tuple(it.music.shape[:2]) != (n_win, window):
                raise ValueError(
                    f"per-window music features {tuple(it.music.shape)} do not match the {n_win} windows of "
                    f"{window} frames of a {it.n_frames}-frame dance (stride {stride})"
                )
            music.append(it.music.to(device).repeat(it.num_samples, 1, 1))
        elif it.music is not None:
            music.append(windows_of(it.music))
        if it.style is not None:
            s = it.style.to(device)
            if per_frame_style:
                style.append(windows_of(s if s.ndim == 2 else s[None].expand(total, -1)))
            else:
                style.append(s[None].expand(rows[-1], -1))
        if any_mask:
            if it.mask is None:
                masks.append(torch.zeros(rows[-1], window, pose_dim, device=device))
                knowns.append(torch.zeros(rows[-1], window, pose_dim, device=device))
                given.append(None)
            else:
                if it.known is None:
                    raise ValueError("a mask needs the known motion it refers to")
                norm_known = normalizer.normalize(it.known.to(device=device, dtype=torch.float32))
                masks.append(windows_of(it.mask.to(torch.float32), pad_value=0.0))
                knowns.append(windows_of(norm_known, pad_value=0.0))
                given.append(it.known.to(device=device, dtype=torch.float32))
    bounds = [0]
    for r in rows:
        bounds.append(bounds[-1] + r)

    def per_dance(fn, x: torch.Tensor) -> torch.Tensor:
        return torch.cat(
            [fn(x[bounds[i] : bounds[i + 1]], layout.n_windows, stride) for i, layout in enumerate(layouts)]
        )

    def share_state(x: torch.Tensor, t_next: int) -> torch.Tensor:
        return per_dance(share_overlaps, x)

    long = any(layout.n_windows > 1 for layout in layouts)
    edge = longform == "edge"
    fuse = long and not edge

    turn = fuse and align_facing
    unedited = [not (any_mask and given[i] is not None) for i in range(len(layouts))]

    def align(x0: torch.Tensor) -> torch.Tensor:
        """Each unedited dance's windows turned to agree on their facing (an edited one keeps its given root)."""
        parts = [x0[bounds[i] : bounds[i + 1]] for i in range(len(layouts))]
        for i, layout in enumerate(layouts):
            if unedited[i] and layout.n_windows > 1:
                turned = align_facings(normalizer.unnormalize(parts[i]), layout.n_windows, stride)
                parts[i] = normalizer.normalize(turned)
        return torch.cat(parts)

    def shape_x0(x0: torch.Tensor) -> torch.Tensor:
        """Turn the windows to agree, fuse their predictions and/or project their rotations onto valid ones."""
        if turn:
            x0 = align(x0)
        if fuse:
            x0 = per_dance(fuse_overlaps, x0)
        if project == "none":
            return x0
        return normalizer.normalize(project_rotations(normalizer.unnormalize(x0), project, skeleton))

    calls = [0]

    def overwrite_after_step(x: torch.Tensor, t_next: int) -> torch.Tensor:
        """EDGE: not the initial noise (the sampler's first call), not after the last step (t_next < 0)."""
        calls[0] += 1
        return x if calls[0] == 1 or t_next < 0 else per_dance(share_overlaps, x)

    generators = [it.generator(device) for it in items]
    if all(g is None for g in generators):
        noise = Noise(None)
    elif any(g is None for g in generators):
        raise ValueError("give every dance of a batch its own seed, or none of them")
    else:
        noise = Noise(generators, rows=rows)
    denoiser = ChunkedDenoiser(sampler.denoiser, chunk_size) if chunk_size > 0 else sampler.denoiser
    run = Sampler(denoiser, sampler.diffusion, style_guidance=sampler.style_guidance, clip_x0=clip_x0)
    x = run.sample(
        (bounds[-1], window, pose_dim),
        Condition(torch.cat(music) if music else None, torch.cat(style) if style else None),
        method=method,
        steps=steps,
        eta=eta,
        guidance=guidance,
        mask=torch.cat(masks) if any_mask else None,
        known=torch.cat(knowns) if any_mask else None,
        step_callback=(overwrite_after_step if edge else share_state) if long else None,
        x0_callback=shape_x0 if fuse or project != "none" else None,
        generator=noise,
        device=device,
        progress=progress,
    )
    if windows:
        return [
            x[bounds[i] : bounds[i + 1]].reshape(it.num_samples, layout.n_windows, window, pose_dim)
            for i, (it, layout) in enumerate(zip(items, layouts))
        ]
    motion = normalizer.unnormalize(x)
    out = []
    for i, (it, layout) in enumerate(zip(items, layouts)):
        part = motion[bounds[i] : bounds[i + 1]].reshape(it.num_samples, layout.n_windows, window, pose_dim)
        dances = torch.stack([stitch_windows(part[s], stride)[: it.n_frames] for s in range(it.num_samples)])
        if any_mask and given[i] is not None:
            # The given channels exactly as given (stitching blends rotations through matrices, and sampling
            # clamps x0 to its bound in normalised units).
            dances = torch.where(it.mask.to(device).bool(), given[i], dances)
        out.append(dances)
    return out


def sample_long(
    sampler: Sampler,
    normalizer: MinMaxNormalizer,
    n_frames: int,
    *,
    music: torch.Tensor | None = None,
    style: torch.Tensor | None = None,
    num_samples: int = 1,
    window: int = 150,
    stride: int = 75,
    mask: torch.Tensor | None = None,
    known: torch.Tensor | None = None,
    method: str = "ddim",
    steps: int | None = 50,
    eta: float = 1.0,
    guidance: Guidance | None = None,
    chunk_size: int = 0,
    generator: torch.Generator | None = None,
    device: torch.device | str = "cpu",
    progress: bool = False,
    skeleton: Skeleton = SMPL24,
) -> torch.Tensor:
    """Generate ``num_samples`` unnormalised motions (S, n_frames, D) of one dance of any length (see
    :func:`sample_items`). music: (n_frames, Da) or None; style: (ds,), per-frame (n_frames, ds) or None;
    mask / known: (n_frames, D) editing mask (1 = given) and the given unnormalised motion."""
    if mask is not None and known is None:
        raise ValueError("a mask needs the known motion it refers to")
    item = DanceRequest(n_frames, music, style, mask, known, num_samples, generator)
    return sample_items(
        sampler, normalizer, [item], window=window, stride=stride, method=method, steps=steps, eta=eta,
        guidance=guidance, chunk_size=chunk_size, device=device, progress=progress, skeleton=skeleton,
    )[0]  # fmt: skip
