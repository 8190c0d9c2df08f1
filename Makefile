# Two commands do everything on a fresh machine: `make demo` and `make test`.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out
# Test processes (pytest-xdist); the Ray tests stay together on one of them (xdist_group "ray").
TEST_WORKERS ?= 2
export HF_HUB_OFFLINE := 1

.PHONY: demo results transfer test bench install clean

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

# The whole story once, on small sizes; the files are listed in the summary it ends with
# (acn/demo.py). The diagnoses follow one chain of effects and fit one value for every joint
# (--auto-alternatives 0 --finest shared: a third of the time of the full search, the same effects
# on these logs); `make results` runs them in full.
demo: $(STAMP)
	@mkdir -p $(OUT) && date +%s > $(OUT)/.demo-started
	# 1. A paired PyBullet -> MuJoCo collection: the built-in trot acts on PyBullet, the same actions drive MuJoCo.
	$(BIN)/acn-collect --source pybullet --target mujoco --policy trot --episodes 8 --seconds 8 \
		--seed 0 --workers 2 --out $(OUT)/trot_pb_mj --overwrite
	# 2. The default corrector (inverse), evaluated in closed loop beside its oracles.
	$(BIN)/acn-fit $(OUT)/trot_pb_mj --rounds 2 --out $(OUT)/acn_inverse --overwrite
	# 3. The same gap answered with physics, beside the corrector, from the same held-out starts.
	$(BIN)/acn-diagnose $(OUT)/trot_pb_mj --side source --model mujoco --auto --auto-alternatives 0 \
		--finest shared --closed-loop 4 --no-oracles --corrector $(OUT)/acn_inverse \
		--json $(OUT)/trot_pb_mj.diagnosis.json --report $(OUT)/trot_pb_mj.report.html \
		--save-model $(OUT)/trot_pb_mj.model.json
	# 4. Measurements with a sealed hidden effect (the answer goes to $(OUT)/hidden.answer.json), diagnosed.
	$(BIN)/acn-collect --source mujoco --policy excite --episodes 6 --seconds 8 --seed 3 --workers 2 \
		--hidden-effect actuator_latency --out $(OUT)/hidden --overwrite
	$(BIN)/acn-diagnose $(OUT)/hidden --model mujoco --auto --auto-alternatives 0 --finest shared \
		--json $(OUT)/hidden.diagnosis.json --report $(OUT)/hidden.report.html \
		--save-model $(OUT)/hidden.model.json
	# 5. A Rerun recording: the hidden log against the fitted model, the error as effects are added.
	$(BIN)/acn-view $(OUT)/hidden --model $(OUT)/hidden.model.json --diagnosis $(OUT)/hidden.diagnosis.json \
		--save $(OUT)/hidden.rrd
	@echo; echo "---- summary ----"
	@$(BIN)/python -m acn.demo $(OUT) $$(cat $(OUT)/.demo-started)

# The README's results tables at full size (in $(OUT)/results): the three acn-fit variants on a
# 12-episode trot, the physics the diagnosis finds there (every catalogue effect, both chains) in
# closed loop beside the corrector and its oracles, a corrector fitted on top of that physics,
# and the hidden log's diagnosis with the per-joint limit scans.
RESULTS := $(OUT)/results
results: $(STAMP)
	@mkdir -p $(RESULTS)
	$(BIN)/acn-collect --source pybullet --target mujoco --policy trot --episodes 12 --seconds 10 \
		--seed 0 --workers 2 --out $(RESULTS)/trot_pb_mj --overwrite
	$(BIN)/acn-fit $(RESULTS)/trot_pb_mj --variant inverse --out $(RESULTS)/acn_inverse --overwrite
	$(BIN)/acn-fit $(RESULTS)/trot_pb_mj --variant paper --epochs 10 --no-oracles --out $(RESULTS)/acn_paper --overwrite
	$(BIN)/acn-fit $(RESULTS)/trot_pb_mj --variant mujoco-jacobian --epochs 10 --no-oracles \
		--out $(RESULTS)/acn_mujoco_jacobian --overwrite
	$(BIN)/acn-diagnose $(RESULTS)/trot_pb_mj --side source --model mujoco --auto --closed-loop 4 \
		--corrector $(RESULTS)/acn_inverse --json $(RESULTS)/trot_pb_mj.diagnosis.json \
		--report $(RESULTS)/trot_pb_mj.report.html --save-model $(RESULTS)/trot_pb_mj.model.json
	$(BIN)/acn-fit $(RESULTS)/trot_pb_mj --model $(RESULTS)/trot_pb_mj.model.json --out $(RESULTS)/acn_on_physics --overwrite
	$(BIN)/acn-collect --source mujoco --policy excite --episodes 6 --seconds 8 --seed 3 --workers 2 \
		--hidden-effect actuator_latency --hidden-effect joint_damping --out $(RESULTS)/hidden --overwrite
	$(BIN)/acn-diagnose $(RESULTS)/hidden --model mujoco --auto --limits-per-joint --closed-loop 4 \
		--json $(RESULTS)/hidden.diagnosis.json --report $(RESULTS)/hidden.report.html \
		--save-model $(RESULTS)/hidden.model.json
	@echo "results in $(RESULTS): acn_*/metrics.json (the correctors), *.diagnosis.json and *.report.html"

# The transfer study in its two settings (README, "Which policy walks on the robot"): the paper's
# (trained in PyBullet, deployed on MuJoCo) and sim-to-real with a hidden effect (trained in nominal
# MuJoCo, deployed on MuJoCo with a sealed actuator latency and joint damping). Each at the default
# sizes; the stage times are printed (71 and 114 minutes when the two ran side by side on 2 cores).
transfer: $(STAMP)
	@mkdir -p $(OUT)
	$(BIN)/acn-transfer --sim pybullet --robot mujoco --out $(OUT)/transfer_paper --overwrite
	$(BIN)/acn-transfer --sim mujoco --robot mujoco --hidden-effect actuator_latency --hidden-effect joint_damping \
		--out $(OUT)/transfer_hidden --overwrite

test: $(STAMP)
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadgroup

bench: $(STAMP)
	$(BIN)/python benchmarks/collect.py
	$(BIN)/python benchmarks/fit.py
	$(BIN)/python benchmarks/view.py
	$(BIN)/python benchmarks/ppo.py
	$(BIN)/python benchmarks/diagnose.py
	$(BIN)/python benchmarks/odometry.py
	$(BIN)/python benchmarks/scale.py
	$(BIN)/python benchmarks/pybullet_resim.py
	$(BIN)/python benchmarks/diagnose_scenarios.py

clean:
	rm -rf $(VENV) $(OUT)
