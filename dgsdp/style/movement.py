"""Movement channels: measured attributes of the dance (its speed, level, arms, travel and turning) that a model
takes as more channels of its style vector (``model.movement_channels``; ``model.speed_conditioning=true`` is the
same as listing ``speed``). They drop with the style (the null style covers them), so classifier-free guidance on
the style guides them too.

Each training window's values are measured on its joints (:mod:`dgsdp.metrics.attributes`), encoded scale-free
(:meth:`dgsdp.trained.TrainedModel.movement_encoding`) and recorded per genre as quantiles, which generation asks
for: the genre's median, or the quantile a description's words ask (:mod:`dgsdp.style.reading`). A word asks an
attribute other than speed at least :data:`ATTRIBUTE_REACH` of all windows' spread away from the genre's median,
even where the genre's own windows hardly vary (a genre that never turns is asked to turn as the genres that do).
"""

from __future__ import annotations

from collections.abc import Iterable

from dgsdp.errors import ConfigError

MOVEMENT_CHANNELS = ("speed", "level", "arms", "travel", "turning")
"""Every movement channel, in the order a style vector carries those a model takes (after the style's own)."""

ATTRIBUTE_REACH = 0.5
"""A word at full strength asks an attribute other than speed at least this many of all training windows'
10th-to-90th percentile spreads away from the genre's median (within all windows' range): a genre's own quantiles
alone can ask for no change a viewer sees (in the synthetic data six genres turn at under 0.01 rad/s in nine
windows of ten, so their 90th percentile asks no turn)."""


def movement_channels(listed: Iterable[str] | None, speed_conditioning: bool = False) -> tuple[str, ...]:
    """The channels a model takes, in :data:`MOVEMENT_CHANNELS`' order, from ``model.movement_channels`` and
    ``model.speed_conditioning`` (true: ``speed`` is one of them)."""
    if isinstance(listed, str):
        raise ConfigError(
            f"model.movement_channels must be a list of names, e.g. [speed, level], got the string {listed!r}"
        )
    names = [str(n) for n in (listed or ())]
    unknown = sorted({n for n in names if n not in MOVEMENT_CHANNELS})
    if unknown:
        raise ConfigError(
            f"model.movement_channels: unknown channel(s) {', '.join(unknown)}; choose from "
            f"{', '.join(MOVEMENT_CHANNELS)}"
        )
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ConfigError(f"model.movement_channels lists {', '.join(repeated)} more than once")
    if speed_conditioning:
        names.append("speed")
    return tuple(c for c in MOVEMENT_CHANNELS if c in names)
