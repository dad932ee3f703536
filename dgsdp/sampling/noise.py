"""Where a sampler's Gaussian draws come from.

One generator for the whole batch (a single song: all its windows share one stream), or one generator per group
of rows (a batch of independent clips, each seeded on its own). With one generator per group, the noise of a
group does not depend on what else is in the batch, so a clip sampled alone and the same clip sampled inside a
batch start from the same noise and follow the same stream.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch


class Noise:
    """Gaussian draws of shape (B, ...) from ``generator``: None (global RNG), one generator, or a sequence of
    generators, each drawing its group of consecutive rows: ``rows[i]`` rows for generator ``i``, or
    ``B // len(generators)`` each when ``rows`` is not given."""

    def __init__(
        self,
        generator: torch.Generator | Sequence[torch.Generator] | None = None,
        rows: Sequence[int] | None = None,
    ) -> None:
        if isinstance(generator, torch.Generator) or generator is None:
            self.generators: list[torch.Generator] | None = None if generator is None else [generator]
        else:
            self.generators = list(generator)
            if not self.generators:
                raise ValueError("Noise needs at least one generator (or None for the global RNG)")
        self.rows = None if rows is None else [int(r) for r in rows]
        if self.rows is not None and (self.generators is None or len(self.rows) != len(self.generators)):
            raise ValueError("Noise needs one row count per generator")

    @classmethod
    def seeded(cls, seeds: Sequence[int], device: torch.device | str = "cpu") -> Noise:
        """One generator per seed (per group of rows)."""
        return cls([torch.Generator(device=device).manual_seed(int(s)) for s in seeds])

    def randn(
        self, shape: Sequence[int], *, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
    ) -> torch.Tensor:
        shape = tuple(int(s) for s in shape)
        if self.generators is None:
            return torch.randn(shape, device=device, dtype=dtype)
        if len(self.generators) == 1:
            return torch.randn(shape, device=device, dtype=dtype, generator=self.generators[0])
        k = len(self.generators)
        rows = self.rows
        if rows is None:
            if shape[0] % k:
                raise ValueError(f"{shape[0]} rows cannot be split among {k} generators")
            rows = [shape[0] // k] * k
        if sum(rows) != shape[0]:
            raise ValueError(f"{shape[0]} rows do not match the generators' groups of {rows} rows")
        return torch.cat(
            [
                torch.randn((r, *shape[1:]), device=device, dtype=dtype, generator=g)
                for g, r in zip(self.generators, rows)
            ]
        )
