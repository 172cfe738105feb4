"""``ctfit`` with every program compiled at the cheapest effort ctfit has ("once": XLA's backend
optimisation level 0, no LLVM expensive passes, no fusion emitters; ``COMPILE_EFFORT`` in
``ctfit/_runtime/stored_programs.py``), for ``bench_fit.py``: a first run on a machine made so
bounds from below what any choice of compile options could make of it. Its programs run slower
(the data's kernels most), so it is run with a cache folder of its own, deleted after.

Run: ``python scripts/_cheapest_compile.py fit FILE ...`` (the ``ctfit`` command's arguments).
"""

from __future__ import annotations

import sys

from ctfit._runtime import stored_programs
from ctfit.cli import console

for effort in stored_programs.COMPILE_EFFORT:
    stored_programs.COMPILE_EFFORT[effort] = dict(stored_programs.COMPILE_EFFORT["once"])
sys.argv = ["ctfit", *sys.argv[1:]]
console()
