# Two commands for a newcomer: `make demo` and `make test`. Each sets up
# everything it needs (virtual environment, packages, generated code) first.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
PROTOS := $(wildcard protos/*.proto)

.PHONY: demo test setup protos kernels check-protos system-deps clean check-arm64

setup: $(STAMP) protos kernels

$(STAMP): pyproject.toml constraints.txt
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[all,dev,cluster,midi]'
	@touch $@

# Generated code is committed; this rebuilds it only when a .proto is newer.
protos: $(STAMP) protos/.generated
protos/.generated: $(PROTOS) protos/generate.py
	$(PY) protos/generate.py
	@touch $@

# The solver's compiled loops go into Numba's cache now, not on the first solve: about 45 s once
# after an install or a change to them, a second when the cache is current.
kernels: $(STAMP)
	@$(PY) -m imaging.compensation.precompile

# Debian packages the tests need, installed when missing (as root, through apt-get; CI runs as
# root): $(call need,CHECK,PACKAGES,WHAT NEEDS THEM).
define need
	@$(1) || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing $(2) ($(3))"; \
	    (apt-get install -y -q $(2) >/dev/null 2>&1 || \
	     (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q $(2) >/dev/null 2>&1)) || \
	     echo "warning: could not install $(2); $(3) will fail"; \
	  else echo "warning: $(2) missing (apt-get install $(2)); $(3) will fail"; fi; }
endef

# iproute2 (ip, tc) builds the virtual venue networks the network tests run on; Xvfb lets the
# fullscreen outputs be tested on a machine with no screen; libSDL2 drives the output without X;
# Debian's chromium and its driver load the operator console in a real browser.
system-deps:
	$(call need,command -v tc >/dev/null 2>&1 && command -v ip >/dev/null 2>&1,iproute2,virtual venue network tests)
	$(call need,command -v Xvfb >/dev/null 2>&1,xvfb,window-output tests)
	$(call need,ldconfig -p | grep -q libSDL2-2.0.so.0,libsdl2-2.0-0,kms-output tests)
	$(call need,command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1,chromium chromium-driver,console browser tests)

demo: setup
	$(VENV)/bin/shadowless demo --out results/demo

# Three workers (pytest-xdist) on the two cores, a test module's tests on one of them (module-scoped
# rigs are set up once): much of a test's time is spent waiting on processes and sockets, so a third
# worker fills it (9:26 against 2 workers' 11:09 for about 1,690 tests, 8:22 for 1,695); each worker's rigs
# advertise an mDNS service of their own, so no worker sees another's. The modules are queued by the time
# their tests took in the last run, the longest first, and bytecode is cached outside the checkout where
# the environment forbids it beside the sources (tests/conftest.py; both in ~/.cache/shadowless-tests,
# SHADOWLESS_TESTS_CACHE=off for neither).
test: setup system-deps
	$(PY) -m pytest -q -n 3 --dist loadfile

# Not part of `make test` (about 10 minutes, as root, with the network): a clean Debian 12 arm64
# root under qemu-user-static installs a node with deploy/install-node.sh, and the node joins a
# coordinator here and renders the x86 node's frame (deploy/check-arm64.sh --help).
check-arm64: setup
	deploy/check-arm64.sh

clean:
	rm -rf $(VENV) results .pytest_cache
