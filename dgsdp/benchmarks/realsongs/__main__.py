"""``python -m dgsdp.benchmarks.realsongs``: see :mod:`dgsdp.benchmarks.realsongs`."""

from dgsdp.benchmarks.realsongs.run import main

raise SystemExit(main())
