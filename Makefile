# Two commands for a newcomer: `make demo` and `make test`. Each sets up
# everything it needs (virtual environment, packages, generated code) first.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
PROTOS := $(wildcard protos/*.proto)

.PHONY: demo test setup protos check-protos system-deps clean

setup: $(STAMP) protos

$(STAMP): pyproject.toml constraints.txt
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[all,dev]'
	@touch $@

# Generated code is committed; this rebuilds it only when a .proto is newer.
protos: $(STAMP) protos/.generated
protos/.generated: $(PROTOS) protos/generate.py
	$(PY) protos/generate.py
	@touch $@

# Xvfb lets the fullscreen-window output be tested on a machine with no screen; iproute2
# (ip, tc) builds the virtual venue networks the network tests run on.
system-deps:
	@command -v tc >/dev/null 2>&1 && command -v ip >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing iproute2 (virtual venue network tests)"; \
	    (apt-get install -y -q iproute2 >/dev/null 2>&1 || \
	     (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q iproute2 >/dev/null 2>&1)) || \
	     echo "warning: could not install iproute2; network tests will fail"; \
	  else echo "warning: ip/tc missing (apt-get install iproute2); network tests will fail"; fi; }
	@command -v Xvfb >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing xvfb (window-output tests)"; \
	    (apt-get install -y -q xvfb >/dev/null 2>&1 || \
	     (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q xvfb >/dev/null 2>&1)) || \
	     echo "warning: could not install xvfb; window-output tests will fail"; \
	  else echo "warning: Xvfb missing (apt-get install xvfb); window-output tests will fail"; fi; }

demo: setup
	$(VENV)/bin/shadowless demo --out results/demo

test: setup system-deps
	$(PY) -m pytest -q

clean:
	rm -rf $(VENV) results .pytest_cache
