"""``python -m dgsdp.quickstart``: the embedded default, end to end, on the CPU in under ten minutes.

1. generates the synthetic AIST++ dataset (``data/synthetic``) if it is not there yet;
2. trains the small model on 1.5 s windows (librosa features, description prompts through the bundled MiniLM text
   encoder, the dance's speed as a style channel);
3. dances to a held-out song of the synthetic dataset in that song's genre, and to the same song with a free-text
   style, with generate.py's default settings, writing the motion (AIST++ pickle), a BVH and a video with the music;
4. prints where everything is, how long each stage took, and the generate.py command for your own songs.

Extra arguments are Hydra overrides for the training run, e.g. ``python -m dgsdp.quickstart trainer.max_steps=50``.
``experiment=<row>`` trains another recipe in place of row 20: ``python -m dgsdp.quickstart
experiment=quickstart_row21`` is the style recipe (row 20 for 12000 steps, 23 minutes on 2 CPU cores;
docs/style.md).
"""

from __future__ import annotations

import logging
import sys
import time
from datetime import datetime
from pathlib import Path

from dgsdp.cli.config import compose_config
from dgsdp.cli.runtime import run_suffix
from dgsdp.errors import DgsdpError
from dgsdp.resources import default_log_dir
from dgsdp.utils.logs import lightning_logs_through_root

FREE_TEXT_STYLE = "sharp, powerful krump with heavy chest pops and arm swings"
# The recipe is experiment=quickstart_row20 (conf/experiment/; one change per row in sweeps/quickstart.yaml): row 9's
# choices below, with the style recipe's conditioning (rows 13-14: the root's own velocity term, the dance's speed as
# a style channel, free text read by the router), the style's ways in at ten times the learning rate (row 17) and
# short windows: 2 s for 2750 steps (row 19), then 1.5 s for 3500 steps (row 20: 3.5 times the updates of row 9's
# 1000 steps on 5 s windows; genre by name 0.86 against 0.46 over three seeds, docs/style.md "Steps to quality").
# Its steps are not the papers' long runs. Row 9's choices were each measured on the same data and seed
# (docs/notes/2026-11-23-real-songs.md and docs/notes/2026-11-25-the-models-own-timing.md):
# - Adan lr 1e-3 instead of 2e-4: the validation loss after 171 steps was 0.23 against 0.41;
# - a weight average over the last ~50 steps (EMA decay 0.98) instead of ~200 (0.995), which in a 500-step run
#   still averages in the first, motionless steps;
# - the reconstruction loss with EDGE's velocity term, without its FK and foot-contact terms (loss=velocity). The
#   foot term holds the feet still wherever a young model predicts a contact (91-100% of frames); without the
#   velocity term the model's frames jitter and its dances to held-out songs move fastest on the beat instead of
#   pausing there (1-2 of 10 above their half-beat-shifted copy; 9-10 of 10 with it);
# - rhythm-only music features (audio.rhythm_only: onset envelope, onset peaks, beats; no MFCC or chroma): the
#   synthetic songs' timbre is nothing like a real song's, and a model that listened to it lost the beat on real
#   songs;
# - 1000 steps instead of 500: the raw dances move at the training data's speed instead of half of it;
# - the pause term (loss.pause=6): the velocity error again where the training dance holds still, which is on the
#   beat; with it the raw dances slow down before the beat as the training dances do;
# - synthetic songs with off-beat layers (data.synthetic.offbeats, the dataset's default; row 7 is row 5 without
#   them): real songs have onsets halfway between the beats, and a model trained on songs without them paused on
#   those too;
# - no dropout (model.dropout=0, row 9; row 5 is the recipe with it): the raw dances' timing target (90% of a
#   real-song set above the half-beat-shifted copy in both BAS variants) held in 4 of 6 seed-and-set runs at
#   guidance 2.5 (3 of 6 at 2) against 1 of 4 for row 5 at 2.5, seed 0 on both sets at both weights, and 1000
#   steps train about 30% faster on 2 CPU cores. Its dances move faster, so the default music guidance is the
#   papers' 2 (2.5 before). Its style accuracy is lower (Table I protocol at w = 2: 0.450 against 0.484 for row 5,
#   seed 0).
QUICKSTART_EXPERIMENT = "quickstart_row20"
QUICKSTART_TRAINING = (f"experiment={QUICKSTART_EXPERIMENT}",)  # its steps, 3500, are the recipe's
# the style recipe: the quick start's row 20 for 12000 steps (docs/style.md)
STYLE_EXPERIMENT = "quickstart_row21"


def _named_experiments(overrides: list[str]) -> list[str]:
    return [o.split("=", 1)[1] for o in overrides if o.lstrip("+").startswith("experiment=")]


def training_experiment(overrides: list[str]) -> str:
    """The experiment the training run uses: the last ``experiment=`` of the overrides, else the quick start's."""
    named = _named_experiments(overrides)
    return named[-1] if named else QUICKSTART_EXPERIMENT


def training_overrides(overrides: list[str]) -> list[str]:
    """The training run's overrides: the quick start's recipe unless the user names an experiment of their own."""
    return list(overrides) if _named_experiments(overrides) else [*QUICKSTART_TRAINING, *overrides]


NEXT_HINT = (
    "      add sampling.guidance.music=<w> to choose how strongly the dance follows the music (classifier-free\n"
    "      guidance; default 2: 1 = plain conditional sampling, higher = more music-driven and more energetic,\n"
    "      too high exaggerates the motion) and seed=<n> for another dance to the same song"
)


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min"


def main(argv: list[str] | None = None) -> int:
    overrides = list(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    lightning_logs_through_root()
    out = default_log_dir() / "quickstart" / f"{datetime.now():%Y-%m-%d_%H-%M-%S}_{run_suffix()}"
    start = time.monotonic()
    try:
        from dgsdp.cli.train import train

        experiment = training_experiment(overrides)
        cfg = compose_config("train", training_overrides(overrides), output_dir=out / "train")
        print(
            f"[1/2] training the small model for {cfg.trainer.max_steps} steps on the synthetic dataset "
            f"({cfg.data.root}; made first if missing) with experiment={experiment}; run folder {out / 'train'}",
            flush=True,
        )
        result = train(cfg)
        checkpoint = result.get("checkpoint")
        if checkpoint is None:
            raise DgsdpError(f"training wrote no checkpoint in {result['checkpoint_dir']}")
        trained = time.monotonic()
        print(f"[1/2] trained in {_minutes(trained - start)}", flush=True)

        from dgsdp.cli.generate import generate, print_report
        from dgsdp.data.aistpp import parse_name, read_split

        test_name = read_split(cfg.data.root, "test")[0]
        parsed = parse_name(test_name)
        song = Path(cfg.data.root) / "wavs" / f"{parsed.music_id}.wav"
        print(f"[2/2] dancing to {song.name} (held-out song, {parsed.genre}) with its genre and a free-text style")
        failed = False
        for style in (parsed.genre, FREE_TEXT_STYLE):
            tag = "genre" if style == parsed.genre else "free_text"
            gen_cfg = compose_config(
                "generate",
                [
                    f"checkpoint={checkpoint}",
                    f"music={song}",
                    f'style="{style}"',
                    f"output_dir={out / 'dances' / tag}",
                    f"paths.cache_dir={cfg.paths.cache_dir}",
                    "device=cpu",
                ],
            )
            report = generate(gen_cfg)
            print_report(report)
            failed |= not report.ok
        print(f"[2/2] danced in {_minutes(time.monotonic() - trained)}", flush=True)
    except DgsdpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"\ncheckpoint: {checkpoint}\ndances:     {out / 'dances'}\ntotal:      {_minutes(time.monotonic() - start)}")
    print(f"next: dgsdp-generate checkpoint={checkpoint} music=<your song> style=<genre or description>")
    print("      (the same as python generate.py ... from a checkout)")
    print(NEXT_HINT)
    if experiment == QUICKSTART_EXPERIMENT:
        print(f"style:  python -m dgsdp.quickstart experiment={STYLE_EXPERIMENT} (about 23 minutes) trains the same\n"
              "      recipe for 12000 steps, whose dances show an asked genre or description more often still\n"
              "      (docs/style.md)")  # fmt: skip
    print(f"faster: dgsdp-train experiment={experiment} distill.teacher={checkpoint}\n"
          "      (from this folder, about 10 minutes) makes a student that samples in one pass per step: use it with\n"
          "      sampling.steps=5, 3-4x faster than this model's default (docs/distillation.md)")  # fmt: skip
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
