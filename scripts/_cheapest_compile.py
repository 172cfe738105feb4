"""``ctfit`` with every program compiled at the cheapest effort ctfit has ("once": XLA's backend
optimisation level 0, no LLVM expensive passes, no fusion emitters; ``ctfit.internal.COMPILE_EFFORT``), for ``bench_fit.py``: a first run on a machine made so
bounds from below what any choice of compile options could make of it. Its programs run slower
(the data's kernels most), so it is run with a cache folder of its own, deleted after.

Run: ``python scripts/_cheapest_compile.py fit FILE ...`` (the ``ctfit`` command's arguments).
"""

from __future__ import annotations

import sys

from ctfit.cli import console
from ctfit.internal import COMPILE_EFFORT

for effort in COMPILE_EFFORT:
    COMPILE_EFFORT[effort] = dict(COMPILE_EFFORT["once"])
sys.argv = ["ctfit", *sys.argv[1:]]
console()
