# Two commands do everything on a fresh machine: `make demo` and `make test`.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out
export HF_HUB_OFFLINE := 1

.PHONY: demo test bench install clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

# Collect a small paired PyBullet -> MuJoCo dataset with the built-in trot.
demo: $(STAMP)
	$(BIN)/acn-collect --source pybullet --target mujoco --policy trot --episodes 4 --seconds 5 \
		--seed 0 --workers 2 --out $(OUT)/trot_pb_mj --overwrite

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python benchmarks/collect.py

clean:
	rm -rf $(VENV) $(OUT)
