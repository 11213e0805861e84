# `make test` and `make bench` bootstrap themselves: they create .venv and
# install the project (with its test extras) when missing or out of date.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
BENCH_OUT ?= bench-out

.PHONY: test bench clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q

bench: $(STAMP)
	$(VENV)/bin/tlsbench main -o $(BENCH_OUT)
	$(VENV)/bin/tlsbench reproduce --quick -o $(BENCH_OUT)/reproduction --db $(BENCH_OUT)/reproduction.sqlite

clean:
	rm -rf $(VENV) $(BENCH_OUT) .pytest_cache
