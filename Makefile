# Two commands set up and use a fresh machine: `make demo` and `make test`.
# Both create .venv if missing, install the project and its Debian needs, and are quiet when re-run.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
APT_STAMP := $(VENV)/.apt-installed
DEBS   := libusb-1.0-0 libgl1 libgomp1 openssl

.PHONY: demo test test-slow lint clean

$(PY):
	python3 -m venv $(VENV)

$(APT_STAMP): | $(PY)
	@scripts/install-debs.sh $(DEBS)
	@touch $@

$(STAMP): pyproject.toml | $(PY)
	@$(PY) -m pip install -q --disable-pip-version-check --upgrade pip 2>/dev/null
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[dev,dask]'
	@touch $@

demo: $(APT_STAMP) $(STAMP)
	$(VENV)/bin/twin demo

test: $(APT_STAMP) $(STAMP)
	$(VENV)/bin/python -m pytest -q -m "not slow"

# The long tests (a few minutes more; CI runs them after `make test`).
test-slow: $(APT_STAMP) $(STAMP)
	$(VENV)/bin/python -m pytest -q -m slow

lint: $(STAMP)
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) .pytest_cache .cache
