# Two commands do everything on a fresh machine: `make demo` and `make test`.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out
# Test processes (pytest-xdist); the Ray tests stay together on one of them (xdist_group "ray").
TEST_WORKERS ?= 2
export HF_HUB_OFFLINE := 1

.PHONY: demo test bench install clean

# Bytecode: pip would compile every installed module on one core, and compileall over the whole
# venv took 91 s on 2 cores here (23,500 files, most never imported). Instead, with bytecode
# writing on, importing every acn module once compiles what the toolkit imports (4,400 files,
# 36 s); a process that later imports anything else writes its bytecode once too. (Where the
# environment sets PYTHONDONTWRITEBYTECODE, every process would compile its imports again.)
unexport PYTHONDONTWRITEBYTECODE
WARM_IMPORTS := import importlib, pkgutil, acn; \
	[importlib.import_module(m.name) for m in pkgutil.walk_packages(acn.__path__, "acn.")]; \
	import ray, pytest, hypothesis, xdist, lerobot.datasets.lerobot_dataset, mujoco.sysid

# uv installs the wheels (9 GB, torch's CUDA libraries most of it) on every core: 1.6 min here
# against pip's 3.5; where uv cannot be installed, pip does it.
$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	if $(BIN)/pip install -qq uv; then $(BIN)/uv pip install --quiet --python $(BIN)/python -e '.[dev,ray]'; \
	else $(BIN)/pip install --quiet --no-compile -e '.[dev,ray]'; fi
	$(BIN)/python -c '$(WARM_IMPORTS)' > /dev/null
	touch $(STAMP)

install: $(STAMP)

# Collect a small paired PyBullet -> MuJoCo dataset with the built-in trot, then fit the default
# corrector (inverse: Gauss-Newton same-state labels; its evaluation prints both oracle bounds),
# the paper's ACN and the MuJoCo-Jacobian variant on it and compare them.
demo: $(STAMP)
	$(BIN)/acn-collect --source pybullet --target mujoco --policy trot --episodes 12 --seconds 10 \
		--seed 0 --workers 2 --out $(OUT)/trot_pb_mj --overwrite
	$(BIN)/acn-fit $(OUT)/trot_pb_mj --variant inverse --out $(OUT)/acn_inverse --overwrite
	$(BIN)/acn-fit $(OUT)/trot_pb_mj --variant paper --epochs 10 --no-oracles --out $(OUT)/acn_paper --overwrite
	$(BIN)/acn-fit $(OUT)/trot_pb_mj --variant mujoco-jacobian --epochs 10 --no-oracles --out $(OUT)/acn_mujoco_jacobian --overwrite
	@echo "dataset: $(OUT)/trot_pb_mj (LeRobotDataset('acn/trot_pb_mj', root='$(OUT)/trot_pb_mj'), HF_HUB_OFFLINE=1)"
	@echo "correctors: $(OUT)/acn_inverse (default), $(OUT)/acn_paper, $(OUT)/acn_mujoco_jacobian (acn.models.Corrector.load(DIR)); metrics.json inside"
	$(BIN)/acn-view $(OUT)/trot_pb_mj --corrector $(OUT)/acn_inverse --save $(OUT)/trot_pb_mj.rrd
	@echo "paired view (source, target, corrected target): rerun $(OUT)/trot_pb_mj.rrd"
	# The same gap answered with physics: which catalogue effects explain PyBullet -> MuJoCo, and a
	# MuJoCo model with them in closed loop beside the corrector and the oracles (same held-out starts).
	$(BIN)/acn-diagnose $(OUT)/trot_pb_mj --side source --model mujoco --auto --closed-loop 4 \
		--corrector $(OUT)/acn_inverse --json $(OUT)/trot_pb_mj.diagnosis.json \
		--report $(OUT)/trot_pb_mj.report.html --save-model $(OUT)/trot_pb_mj.model.json
	@echo "physics vs network on the trot gap: $(OUT)/trot_pb_mj.report.html, $(OUT)/trot_pb_mj.diagnosis.json (closed_loop)"
	# Both at once: a corrector fitted on top of that physics model learns what its effects leave
	# (its evaluation: the physics model alone, with the corrector, and the oracles of the physics model).
	$(BIN)/acn-fit $(OUT)/trot_pb_mj --model $(OUT)/trot_pb_mj.model.json --out $(OUT)/acn_on_physics --overwrite
	@echo "corrector on top of the physics model: $(OUT)/acn_on_physics (metrics.json: closed_loop)"
	# Measurements with two hidden effects (the answer goes to $(OUT)/hidden.answer.json), then the diagnosis:
	# compare, where, rank the catalogue, add effects while the error falls, what the log rules out, report.
	$(BIN)/acn-collect --source mujoco --policy excite --episodes 6 --seconds 8 --seed 3 --workers 2 \
		--hidden-effect actuator_latency --hidden-effect joint_damping --out $(OUT)/hidden --overwrite
	$(BIN)/acn-diagnose $(OUT)/hidden --model mujoco --auto --limits-per-joint --closed-loop 4 \
		--json $(OUT)/hidden.diagnosis.json --report $(OUT)/hidden.report.html --save-model $(OUT)/hidden.model.json
	@echo "diagnosis: $(OUT)/hidden.report.html (HTML), $(OUT)/hidden.diagnosis.json, fitted model $(OUT)/hidden.model.json"
	@echo "the hidden answer: $(OUT)/hidden.answer.json"
	$(BIN)/acn-view $(OUT)/hidden --model $(OUT)/hidden.model.json --diagnosis $(OUT)/hidden.diagnosis.json --save $(OUT)/hidden.rrd
	@echo "diagnosis view (measured vs model, residuals, error as effects are added): rerun $(OUT)/hidden.rrd"

test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadgroup

bench: $(STAMP)
	$(BIN)/python benchmarks/collect.py
	$(BIN)/python benchmarks/fit.py
	$(BIN)/python benchmarks/view.py
	$(BIN)/python benchmarks/ppo.py
	$(BIN)/python benchmarks/diagnose.py
	$(BIN)/python benchmarks/odometry.py
	$(BIN)/python benchmarks/scale.py

clean:
	rm -rf $(VENV) $(OUT)
