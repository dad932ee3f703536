"""Benchmark of the vectorised kinetic and geometric features against a per-frame Python loop.

``python -m dgsdp.benchmarks.metrics`` times both feature sets on 100 random motions of 300 frames,
times the loop version on a few of them, extrapolates, and prints the speed-up and the largest
difference between the two.

The loop version below is written directly from the written definitions (one frame, one joint and
one window term at a time, the way the reference implementations compute them) and shares no code
with ``dgsdp.metrics``, so the tests also use it as an independent check of the vectorised code.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

JOINT_NAMES = [
    "root", "lhip", "rhip", "belly", "lknee", "rknee", "spine", "lankle", "rankle", "chest", "ltoes",
    "rtoes", "neck", "linshoulder", "rinshoulder", "head", "lshoulder", "rshoulder", "lelbow", "relbow",
    "lwrist", "rwrist", "lhand", "rhand",
]  # fmt: skip
HL, SW, HW = 0.2568381092115207, 0.39084835854945527, 0.11924706586886204  # humerus, shoulders, hips (m)


def kinetic_features_loop(joints: np.ndarray, fps: float = 60, mode: str = "paper") -> np.ndarray:
    """Kinetic features of one y-up motion (T, 24, 3), frame by frame: (72,)."""
    p = np.asarray(joints, dtype=np.float64)
    n_frames = len(p)
    ft = 1.0 / fps
    out = []
    for j in range(p.shape[1]):
        ke_h = ke_v = energy = 0.0
        for i in range(1, n_frames):
            total = np.zeros(3)
            count = 0
            for k in range(i - 2, i + 3):
                if 1 <= k <= n_frames - 1:
                    total += p[k, j] - p[k - 1, j]
                    count += 1
            velocity = total / (count * ft)
            ke_h += velocity[0] ** 2 + velocity[2] ** 2
            ke_v += velocity[1] ** 2
            acc = np.zeros(3)
            count = 0
            for offset in range(-2, 3):
                k = i + offset
                if k - 1 < 0 or k + 1 >= n_frames:
                    continue
                v2 = (p[k + 1, j] - p[k, j]) / ft
                if mode == "paper":
                    v1 = p[k, j] - p[k - 1, j] / ft
                else:
                    v1 = (p[k, j] - p[k - 1, j]) / ft
                acc += (v2 - v1) / ft
                count += 1
            energy += np.linalg.norm(acc / count) if count else 0.0
        out += [ke_h / (n_frames - 1), ke_v / (n_frames - 1), energy / (n_frames - 1)]
    return np.array(out)


class _LoopFrame:
    """Positions of one frame and the frame before it, looked up by joint or virtual-point name."""

    def __init__(self, p: np.ndarray, t: int, mode: str, fps: float) -> None:
        self.p, self.t, self.mode = p, t, mode
        self.scale = 120.0 if mode == "paper" else fps

    def at(self, name: str, previous: bool = False) -> np.ndarray:
        frame = self.p[self.t - 1] if previous else self.p[self.t]
        if name == "zero":
            return np.zeros(3)
        if name == "y_unit":
            return np.array([0.0, 1.0, 0.0])
        if name == "minus_y_unit":
            return np.array([0.0, -1.0, 0.0])
        if name == "y_min":
            return np.array([0.0, min(frame[:, 1]), 0.0])
        return frame[JOINT_NAMES.index(name)]

    def plane(self, a, b, c, q, th):
        a, b, c, q = (self.at(n) for n in (a, b, c, q))
        n = np.cross(c - a, b - a)
        return np.dot(q - a, n) / np.linalg.norm(n) > th

    def nplane(self, n1, n2, a, q, th):
        n1, n2, a, q = (self.at(n) for n in (n1, n2, a, q))
        n = n2 - n1
        return np.dot(q - a, n) / np.linalg.norm(n) > th

    def angle(self, j1, j2, k1, k2, bounds):
        j = self.at(j2) - self.at(j1)
        k = self.at(k2) - self.at(k1)
        deg = math.degrees(math.acos(np.dot(j, k) / (np.linalg.norm(j) * np.linalg.norm(k))))
        return bounds[0] < deg < bounds[1]

    def _relative(self, moving, origin):
        now = self.at(moving) - self.at(origin)
        before = self.at(moving, previous=True) - self.at(origin, previous=True)
        return (now - before) * self.scale

    def move(self, j1, j2, j3, j4, th):
        velocity = self._relative(j3, j1) if self.mode == "paper" else self._relative(j4, j3)
        d = self.at(j2) - self.at(j1)
        return np.dot(velocity, d) / np.linalg.norm(d) > th

    def nmove(self, j1, j2, j3, j4, th):
        d = np.cross(self.at(j3) - self.at(j1), self.at(j2) - self.at(j1))
        return np.dot(self._relative(j4, j1), d) / np.linalg.norm(d) > th

    def fast(self, j, th):
        return np.linalg.norm(self.at(j) - self.at(j, previous=True)) * self.scale > th


def _frame_flags(f: _LoopFrame) -> list[bool]:
    return [
        f.nmove("neck", "rhip", "lhip", "rwrist", 1.8 * HL),
        f.nmove("neck", "lhip", "rhip", "lwrist", 1.8 * HL),
        f.nplane("chest", "neck", "neck", "rwrist", 0.2 * HL),
        f.nplane("chest", "neck", "neck", "lwrist", 0.2 * HL),
        f.move("belly", "chest", "chest", "rwrist", 1.8 * HL),
        f.move("belly", "chest", "chest", "lwrist", 1.8 * HL),
        f.angle("relbow", "rshoulder", "relbow", "rwrist", (0, 110)),
        f.angle("lelbow", "lshoulder", "lelbow", "lwrist", (0, 110)),
        f.nplane("lshoulder", "rshoulder", "lwrist", "rwrist", 2.5 * SW),
        f.move("lwrist", "rwrist", "rwrist", "lwrist", 1.4 * HL),
        f.move("rwrist", "root", "lwrist", "root", 1.4 * HL),
        f.move("lwrist", "root", "rwrist", "root", 1.4 * HL),
        f.fast("rwrist", 2.5 * HL),
        f.fast("lwrist", 2.5 * HL),
        f.plane("root", "lhip", "ltoes", "rankle", 0.38 * HL),
        f.plane("root", "rhip", "rtoes", "lankle", 0.38 * HL),
        f.nplane("zero", "y_unit", "y_min", "rankle", 1.2 * HL),
        f.nplane("zero", "y_unit", "y_min", "lankle", 1.2 * HL),
        f.nplane("lhip", "rhip", "lankle", "rankle", 2.1 * HW),
        f.angle("rknee", "rhip", "rknee", "rankle", (0, 110)),
        f.angle("lknee", "lhip", "lknee", "lankle", (0, 110)),
        f.fast("rankle", 2.5 * HL),
        f.fast("lankle", 2.5 * HL),
        f.angle("neck", "root", "rshoulder", "relbow", (25, 180)),
        f.angle("neck", "root", "lshoulder", "lelbow", (25, 180)),
        f.angle("neck", "root", "rhip", "rknee", (50, 180)),
        f.angle("neck", "root", "lhip", "lknee", (50, 180)),
        f.plane("rankle", "neck", "lankle", "root", 0.5 * HL),
        f.angle("neck", "root", "zero", "y_unit", (70, 110)),
        f.nplane("zero", "minus_y_unit", "y_min", "rwrist", -1.2 * HL),
        f.nplane("zero", "minus_y_unit", "y_min", "lwrist", -1.2 * HL),
        f.fast("root", 2.3 * HL),
    ]


def geometric_features_loop(joints: np.ndarray, fps: float = 60, mode: str = "paper") -> np.ndarray:
    """Geometric features of one y-up motion (T, 24, 3), frame by frame: (32,)."""
    p = np.asarray(joints, dtype=np.float64)
    flags = [_frame_flags(_LoopFrame(p, t, mode, fps)) for t in range(1, len(p))]
    return np.array(flags, dtype=np.float64).mean(axis=0)


def random_motions(n_sequences: int, n_frames: int, seed: int = 0) -> np.ndarray:
    """Random-walk joint positions (N, T, 24, 3) around a rough standing pose, in metres."""
    rng = np.random.default_rng(seed)
    pose = rng.normal(scale=0.3, size=(1, 1, 24, 3)) + np.array([0.0, 1.0, 0.0])
    steps = rng.normal(scale=0.01, size=(n_sequences, n_frames, 24, 3))
    return pose + np.cumsum(steps, axis=1)


def run(
    n_sequences: int = 100, n_frames: int = 300, n_loop: int = 3, mode: str = "paper", repeats: int = 3
) -> dict[str, float]:
    """Time vectorised (best of ``repeats``) and loop features (``n_loop`` sequences, extrapolated).

    Returns timings in seconds, the speed-up and the largest differences on the loop subset.
    """
    from dgsdp.metrics import geometric_features_batch, kinetic_features_batch

    motions = random_motions(n_sequences, n_frames)
    vectorised_s = math.inf
    for _ in range(repeats):  # the first pass also pays for memory first-touch: keep the best
        start = time.perf_counter()
        fast_k = kinetic_features_batch(motions, mode=mode)
        fast_g = geometric_features_batch(motions, mode=mode)
        vectorised_s = min(vectorised_s, time.perf_counter() - start)

    start = time.perf_counter()
    loop_k = np.stack([kinetic_features_loop(m, mode=mode) for m in motions[:n_loop]])
    loop_g = np.stack([geometric_features_loop(m, mode=mode) for m in motions[:n_loop]])
    loop_subset_s = time.perf_counter() - start
    loop_s = loop_subset_s * n_sequences / n_loop

    rel_k = np.abs(fast_k[:n_loop] - loop_k) / np.maximum(np.abs(loop_k), 1.0)
    return {
        "vectorised_s": vectorised_s,
        "loop_extrapolated_s": loop_s,
        "speedup": loop_s / vectorised_s,
        "max_abs_diff_kinetic": float(np.abs(fast_k[:n_loop] - loop_k).max()),
        "max_rel_diff_kinetic": float(rel_k.max()),
        "max_abs_diff_geometric": float(np.abs(fast_g[:n_loop] - loop_g).max()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=100)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--loop-subset", type=int, default=3, help="sequences timed with the loop version")
    parser.add_argument("--mode", choices=["paper", "corrected"], default="paper")
    args = parser.parse_args()
    r = run(args.sequences, args.frames, args.loop_subset, args.mode)
    print(f"kinetic + geometric features, {args.sequences} x {args.frames} frames, mode={args.mode}")
    print(f"  vectorised:            {r['vectorised_s']:.3f} s (best of 3)")
    print(f"  per-frame loop:        {r['loop_extrapolated_s']:.1f} s (extrapolated from {args.loop_subset})")
    print(f"  speed-up:              {r['speedup']:.0f}x")
    print(f"  max |diff| kinetic:    {r['max_abs_diff_kinetic']:.3g} (relative {r['max_rel_diff_kinetic']:.3g})")
    print(f"  max |diff| geometric:  {r['max_abs_diff_geometric']:.3g}")


if __name__ == "__main__":
    main()
