"""Quality versus sampling steps: one checkpoint evaluated with DDPM-1000, DDIM-50 and the few-step solvers.

``python -m dgsdp.benchmarks.sampling_quality --checkpoint <ckpt> [--settings ddim-50 dpmpp_2m-10 ...]
[--trials 3] [--clips-per-trial N] [--out docs-table.md]`` runs ``evaluate.py`` once per setting (the Table I
protocol: 5 s clips of the test music, guidance w = 2), each with ``protocol.trials`` trials seeded seed, seed+1,
... (so the spread is over seeds and, with ``--clips-per-trial``, over the clips drawn), and times each setting's
sampling of one batch of 5 s clips directly on the checkpoint (seconds of compute per second of dance). It writes
a markdown table of FID_k, FID_g, Div_k, Div_g, BAS, PFC and StyleAcc (mean ± std over trials) after every
setting, so a partial run leaves the rows it finished.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from dgsdp.sampling import check_method

DEFAULT_SETTINGS = ["ddim-50", "dpmpp_2m-25", "dpmpp_2m-10", "dpmpp_2m-5", "unipc-25", "unipc-10", "unipc-5",
                    "ddpm-1000"]  # fmt: skip
COLUMNS = [("FID_k", "FID_k"), ("FID_g", "FID_g"), ("Div_k", "Div_k"), ("Div_g", "Div_g"), ("BeatAlign", "BAS"),
           ("PFC", "PFC"), ("StyleAcc", "StyleAcc")]  # fmt: skip
ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Setting:
    method: str
    steps: int
    eta: float | None = None
    bf16: bool = False

    def overrides(self) -> list[str]:
        """evaluate.py's sampling overrides for this setting."""
        out = [f"sampling.method={self.method}", f"sampling.steps={self.steps}"]
        if self.eta is not None:
            out.append(f"sampling.eta={self.eta}")
        return out + (["sampling.bf16=true"] if self.bf16 else [])


def parse_setting(text: str) -> Setting:
    """``<method>-<steps>``, optionally ``-eta<eta>`` (DDIM) and ``-bf16`` (bf16 autocast), e.g. ``ddim-50-eta0``
    or ``dpmpp_2m-10-bf16``."""
    method, *rest = text.split("-")
    try:
        steps = int(rest.pop(0))
        eta = float(rest.pop(0)[3:]) if rest and rest[0].startswith("eta") else None
        bf16 = rest == ["bf16"]
        if rest and not bf16:
            raise ValueError
    except (IndexError, ValueError):
        raise ValueError(
            f"setting {text!r}: use <method>-<steps>[-eta<eta>][-bf16], e.g. dpmpp_2m-10 or dpmpp_2m-10-bf16"
        ) from None
    check_method(method)
    return Setting(method, steps, eta, bf16)


def evaluate_setting(checkpoint: str, setting: Setting, out_dir: Path, overrides: list[str]) -> dict:
    """Run evaluate.py (a subprocess: its command line is the stable interface) and return its results.json."""
    cmd = [sys.executable, str(ROOT / "evaluate.py"), f"checkpoint={checkpoint}", "protocol=table1",
           *setting.overrides(), "protocol.guidance_weights=[2.0]", "progress=false", "logger=none",
           f"hydra.run.dir={out_dir}", *overrides]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"evaluate.py failed for {setting}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return json.loads(next(out_dir.rglob("results.json")).read_text())


def time_setting(checkpoint: str, setting: Setting, *, clips: int, seconds: float = 5.0) -> float:
    """Seconds of sampling compute per second of dance for one batch of ``clips`` clips (guidance w = 2)."""
    from dgsdp.generation import DanceGenerator, DanceRequest
    from dgsdp.sampling import GuidanceSettings, SamplingSettings
    from dgsdp.trained import load_model

    model = load_model(checkpoint).eval()
    generator = DanceGenerator(model, cache_dir=tempfile.mkdtemp(prefix="dgsdp-bench-"))
    n = int(round(seconds * 30))
    gen = torch.Generator().manual_seed(0)
    dims = model.spec.conditioning
    requests = [
        DanceRequest(
            n,
            music=torch.randn(n, dims.audio_dim, generator=gen) if dims.audio_dim else None,
            style=torch.randn(dims.style_dim, generator=gen) if dims.style_dim else None,
            seed=i,
        )
        for i in range(clips)
    ]
    settings = SamplingSettings(
        method=setting.method, steps=setting.steps, eta=1.0 if setting.eta is None else setting.eta,
        guidance=GuidanceSettings(music=2.0), batch_size=clips, bf16=setting.bf16,
    )  # fmt: skip
    start = time.perf_counter()
    generator.generate_many(requests, settings)
    return (time.perf_counter() - start) / (clips * seconds)


def fmt(summary: dict | None, digits: int = 2) -> str:
    if not summary or summary.get("mean") is None:
        return "n/a"
    return f"{summary['mean']:.{digits}f} ± {summary['std']:.{digits}f}"


def write_table(path: Path, rows: list[tuple[str, dict, float]], header: str) -> None:
    lines = [header, "", "| sampler | " + " | ".join(c for _, c in COLUMNS) + " | compute s per s of dance |",
             "|---" * (len(COLUMNS) + 2) + "|"]  # fmt: skip
    for name, metrics, sps in rows:
        digits = {"PFC": 3, "BeatAlign": 3, "StyleAcc": 3}
        cells = [fmt(metrics.get(key), digits.get(key, 2)) for key, _ in COLUMNS]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {sps:.3f} |")
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--settings", nargs="+", default=DEFAULT_SETTINGS, help="<method>-<steps>[-bf16] each")
    parser.add_argument("--trials", type=int, default=3, help="trials (seeds) per setting")
    parser.add_argument("--clips-per-trial", type=int, default=None, help="clips per trial (default: every clip)")
    parser.add_argument("--timing-clips", type=int, default=10, help="clips in the timed batch")
    parser.add_argument("--work-dir", default="outputs/sampling_quality")
    parser.add_argument("--out", default="sampling_quality.md", help="markdown table written here")
    parser.add_argument("--timing-only", type=int, default=0, metavar="REPEATS",
                        help="only time the settings, in this many interleaved repeats (medians)")  # fmt: skip
    parser.add_argument("overrides", nargs="*", help="more evaluate.py overrides (key=value)")
    args = parser.parse_args(argv)
    settings = [parse_setting(s) for s in args.settings]
    if args.timing_only:
        times: dict[str, list[float]] = {text: [] for text in args.settings}
        for _ in range(args.timing_only):
            for text, setting in zip(args.settings, settings, strict=True):
                times[text].append(time_setting(args.checkpoint, setting, clips=args.timing_clips))
        for text, ts in times.items():
            print(f"{text}: {statistics.median(ts):.4f} s per s of dance (median of {len(ts)})", flush=True)
        return
    overrides = [f"protocol.trials={args.trials}", *args.overrides]
    if args.clips_per_trial:
        overrides.append(f"protocol.clips_per_trial={args.clips_per_trial}")
    work = Path(args.work_dir)
    header = (f"Checkpoint `{Path(args.checkpoint).name}`, protocol table1 (5 s clips, guidance w = 2), "
              f"{args.trials} trials (seeds), overrides: {' '.join(overrides)}")  # fmt: skip
    rows = []
    for text, setting in zip(args.settings, settings, strict=True):
        start = time.perf_counter()
        results = evaluate_setting(args.checkpoint, setting, work / text, overrides)
        row = next(r for r in results["rows"] if r["kind"] == "generated")
        sps = time_setting(args.checkpoint, setting, clips=args.timing_clips)
        rows.append((text, row["metrics"], sps))
        write_table(Path(args.out), rows, header)
        print(f"{text}: {time.perf_counter() - start:.0f} s, {sps:.3f} s per s of dance", flush=True)


if __name__ == "__main__":
    main()
