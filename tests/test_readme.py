"""The README's examples, read as a new user would run them after ``make fit`` (issue 24): the
command's place is said before it is used, every file an example writes lies in ``out/``, and
every file it reads is in the repository or written by an earlier line."""

import re
import shlex

from conftest import ROOT

README = (ROOT / "README.md").read_text()
OUTPUT_OPTIONS = ("-o", "--output", "--backend", "--plot", "--idata")


def _commands() -> list[list[str]]:
    blocks = re.findall(r"```sh\n(.*?)```", README, flags=re.S)
    lines = [line.split("  #")[0].strip() for block in blocks for line in block.splitlines()]
    return [shlex.split(line) for line in lines if line.startswith("ctfit ")]


def test_the_readme_says_where_the_command_is_before_using_it():
    assert README.index("source .venv/bin/activate") < README.index("ctfit simulate")


def test_every_example_writes_into_out_and_reads_what_exists_or_was_written():
    commands = _commands()
    assert len(commands) >= 10
    written: set[str] = set()
    for words in commands:
        outputs = {words[i + 1] for i, w in enumerate(words[:-1]) if w in OUTPUT_OPTIONS}
        assert all(o.startswith("out/") for o in outputs), words
        if words[1] == "sample" and "-o" not in words:
            outputs.add(words[2].removesuffix(".json") + ".posterior.json")
        inputs = [w for w in words[2:] if "/" in w and w not in outputs and not w.startswith("-")]
        for path in inputs:
            here = list(ROOT.glob(path)) if "*" in path else [ROOT / path]
            assert any(p.exists() for p in here) or path.rstrip("/") in written, (path, words)
        written |= {o.rstrip("/") for o in outputs}
    python = re.search(r"```python\n(.*?)```", README, flags=re.S).group(1)
    for path in re.findall(r'"([^"]+\.csv)"', python):
        assert (ROOT / path).exists() or path in written, path
