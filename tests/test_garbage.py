"""The ``ctfit`` command collects cyclic garbage seldom, but still collects it
(``ctfit._runtime.garbage``); a program that imports ctfit keeps its own settings."""

import subprocess
import sys

from ctfit._runtime.garbage import YOUNG_COLLECTION


def _python(code: str) -> str:
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_the_console_script_sets_the_threshold_before_the_command_runs():
    """Seen from inside the command (``main`` replaced by a probe), before it imports anything heavy."""
    out = _python(
        "import gc, sys\n"
        "import ctfit._cli.commands as commands\n"
        "commands.main = lambda: print(gc.get_threshold(), 'jax' in sys.modules, flush=True)\n"
        "from ctfit._cli.leave import console\n"
        "console()\n"
    )
    assert out.split("\n")[0] == f"({YOUNG_COLLECTION}, 10, 10) False"


def test_a_program_importing_ctfit_keeps_pythons_thresholds():
    import gc

    before = gc.get_threshold()
    out = _python("import gc, ctfit, ctfit.cli; from ctfit._cli import leave; print(gc.get_threshold())")
    assert out.strip() == str(before) == "(700, 10, 10)"


def test_garbage_in_cycles_is_still_collected():
    """Cycles holding large arrays, made one after another: the collector frees them as the new
    objects pass the threshold, so they never pile up (each holds 1 MiB; 400 of them: 400 MiB)."""
    out = _python(
        "import gc, numpy as np\n"
        "from ctfit._runtime.garbage import YOUNG_COLLECTION, collect_seldom\n"
        "collect_seldom()\n"
        "runs = []\n"
        "gc.callbacks.append(lambda phase, info: runs.append(info['collected']) if phase == 'stop' else None)\n"
        "import weakref\n"
        "class Node:\n"
        "    pass\n"
        "alive = weakref.WeakSet()\n"
        "most = 0\n"
        "for i in range(400):\n"
        "    a, b = Node(), Node()\n"
        "    a.other, b.other, a.payload = b, a, np.ones(1 << 17)\n"
        "    a.filler = [[] for _ in range(2_000)]  # container objects: what the threshold counts\n"
        "    alive.add(a)\n"
        "    del a, b\n"
        "    most = max(most, len(alive))\n"
        "print(len(runs), sum(runs), most, YOUNG_COLLECTION)\n"
    )
    runs, collected, most, threshold = map(int, out.split())
    assert runs >= 1 and collected > 0
    assert threshold == YOUNG_COLLECTION
    assert most <= 2 + YOUNG_COLLECTION // 2_000  # at most a threshold's worth of cycles waits for the collector
