"""acn-diagnose on data with hidden effects: the effect is named, fitted and its error removed;
nominal data gives "none", physics outside the catalogue gives "unexplained"."""

from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from robot_log import LogSpec, welded_payload, write_log

from acn.datasets.checks import repeated_transitions
from acn.datasets.measurements import load_measurements
from acn.datasets.record import record
from acn.errors import UserError
from acn.models.diagnose import DiagnoseConfig, diagnose
from acn.models.diagnose.problem import prepare
from acn.models.diagnose.rank import doubt
from acn.models.diagnose.report import terminal, to_json, write_html
from acn.toolkit.collector import CollectConfig
from acn.toolkit.effects import AppliedEffect, Model, get_effect
from acn.toolkit.state import GROUPS, JOINT_NAMES, SLICES, STATE_NAMES

# Small and quick: a few hundred rows, a few hundred re-simulated per stage.
FAST = DiagnoseConfig(horizons=(1, 5), compare_rows=300, rollout_starts=30, rank_rows=100, judge_rows=300,
                      fit_rows=200, rank_iterations=2)


def measured(tmp_path, hidden: dict, policy: str = "excite", source: str = "mujoco", seconds: float = 3.0,
             episodes: int = 2, seed: int = 0):
    """Measurements recorded by acn-collect with hidden effects, read back through LeRobotDataset."""
    effects = [AppliedEffect(get_effect(n), get_effect(n).parse(v)) for n, v in hidden.items()]
    cfg = CollectConfig(source=source, target=None, policy=policy, episodes=episodes, seconds=seconds, seed=seed,
                        hidden_effects=effects)
    path = record(cfg, tmp_path / "measured")
    return load_measurements(path)


def close(fitted, true, rel: float = 0.2) -> bool:
    """Within ``rel`` of the truth; a per-joint parameter as a vector (its norm)."""
    fitted, true = np.atleast_1d(np.asarray(fitted, float)), np.atleast_1d(np.asarray(true, float))
    true = np.broadcast_to(true, fitted.shape)
    return bool(np.linalg.norm(fitted - true) <= rel * np.linalg.norm(true))


OFFSETS = [0.05, -0.08, 0.1, -0.04, 0.06, -0.12, 0.03, 0.09, -0.07, -0.1, 0.04, 0.08]
# effect -> (hidden params, policy that excites it). Two effects are left to other tests, for time:
# actuator latency is ranked first over the whole catalogue and fitted on a noisy log of another
# controller, on PyBullet data and on a log without motion capture (test_odometry); motor strength
# is ranked first and fitted where both PD gains are scaled alike, and added by acn-diagnose --add.
CASES = {
    "joint_damping": ({"value": 0.4}, "excite"),
    "joint_friction": ({"value": 0.3}, "excite"),
    "armature": ({"value": 0.015}, "excite"),
    "torque_limit": ({"value": 18.0}, "excite"),
    "pd_gains": ({"kp_scale": 0.85, "kd_scale": 0.55}, "excite"),  # equal scales would be motor_strength
    "payload": ({"mass": 2.0, "com_x": 0.04, "com_y": -0.02, "com_z": 0.03}, "excite"),
    "ground_friction": ({"value": 0.4}, "trot"),
    "ground_softness": ({"timeconst": 0.05}, "trot"),  # the feet sink 11 mm standing (1.3 nominal)
    "encoder_offset": ({"value": OFFSETS}, "excite"),
    "backlash": ({"value": 0.03}, "excite"),
    # a motion-capture body (or PyBullet's centre of mass and principal axes) instead of the trunk frame
    "base_frame_offset": ({"x": 0.03, "y": -0.02, "z": 0.04, "roll": 0.03, "pitch": -0.04}, "excite"),
}


# Where the added effect's granularity is chosen among all four (the others: one value for every
# joint, as hidden; time)
CHOOSES_GRANULARITY = ("joint_damping", "joint_friction")


@pytest.mark.parametrize("name", list(CASES))
def test_each_hidden_effect_is_ranked_first_fitted_and_removed(tmp_path, name):
    params, policy = CASES[name]
    cfg = FAST if name in CHOOSES_GRANULARITY else replace(FAST, finest="shared")
    d = diagnose(measured(tmp_path, {name: params}, policy), Model.parse("mujoco"), cfg, add=[name])
    assert d.ranking[0].name == name, [(c.name, c.score) for c in d.ranking[:3]]
    assert d.verdict == "effect", d.reason
    fitted = d.added[0].fit.values
    for key, true in params.items():
        if key.startswith("com_"):
            continue
        # twelve offsets: within 10 % (17 % here before add.refine_chain's central differences; 3.8 % with them)
        assert close(fitted[key], true, 0.1 if name == "encoder_offset" else 0.2), (key, fitted[key], true)
    if name == "payload":
        com = np.array([fitted[k] for k in ("com_x", "com_y", "com_z")])
        true = np.array([params[k] for k in ("com_x", "com_y", "com_z")])
        assert np.linalg.norm(com - true) <= 0.2 * np.linalg.norm(true), com
    added = d.added[0]
    assert added.fit.granularity == ("joint" if name == "encoder_offset" else "shared"), added.fit.granularity
    assert added.judgement.removed >= 0.8 and added.judgement.explained(d.floor_mse) >= 0.8
    assert added.after.headline < added.before.headline
    if name == "encoder_offset":  # refined once: a chain compared refined (add.other_starts) is not refined again
        from acn.models.diagnose.add import refine_chain

        residual = d.problem.residual_of(Model.parse("mujoco").sim_config(d.problem.control), d.judge_rows)
        assert added.refined and refine_chain(d.problem, d.before, d.added, cfg, d.judge_rows, residual) is d.added


def test_gains_scaled_alike_are_named_the_simpler_motor_strength(tmp_path):
    # Both PD gains scaled by about the same factor is a weaker motor: one parameter explains it.
    data = measured(tmp_path, {"pd_gains": {"kp_scale": 0.75, "kd_scale": 0.8}})
    d = diagnose(data, Model.parse("mujoco"), FAST)
    scores = {c.name: c.judgement.removed for c in d.ranking}
    assert d.ranking[0].name == "motor_strength", [(c.name, c.score) for c in d.ranking[:3]]
    assert scores["motor_strength"] >= 0.9 * scores["pd_gains"]
    assert 0.7 <= float(np.mean(d.ranking[0].fit.values["scale"])) <= 0.85


def test_two_effects_together_are_both_found(tmp_path):
    data = measured(tmp_path, {"actuator_latency": {"seconds": 0.01}, "joint_damping": {"value": 0.5}})
    # Time: among the candidates that look like them, one value for every joint, and no chain from
    # the runner-up (other_starts and the report of every chain: the next test; the whole catalogue
    # at every granularity, runner-up chains included: benchmarks/diagnose_cases.py --pairs)
    cfg = replace(FAST, finest="shared", candidates=("actuator_latency", "joint_damping", "joint_friction", "pd_gains"),
                  auto_alternatives=0)
    d = diagnose(data, Model.parse("mujoco"), cfg, automatic=True)
    names = [a.name for a in d.added]
    assert set(names[:2]) == {"actuator_latency", "joint_damping"}, names
    assert [c.names for c in d.chains] == [names] and d.chains[0].kept, [c.to_json() for c in d.chains]
    values = {t.name: t.values for t in d.final.model.effects}  # each effect refitted as the next one came in
    assert close(values["actuator_latency"]["seconds"], 0.01) and close(values["joint_damping"]["value"], 0.5)
    assert d.verdict == "effect" and d.final.headline < 0.2 * d.before.headline


def test_a_candidate_whose_final_fit_is_set_aside_gives_way_to_the_runner_up(tmp_path, monkeypatch):
    # A final fit (more rows, chosen granularity) can turn implausible where the ranking's fit was
    # not (seen on the trot gap with a bound too high for ground_softness). The chain goes on with
    # the runner-up, and the verdict never names the effect set aside. The real rule is replaced
    # by one that refuses the true effect, so the path runs on every machine.
    from acn.models.diagnose import add

    real = add.final_doubt
    monkeypatch.setattr(add, "final_doubt", lambda step: "refused for the test" if step.name == "joint_damping"
                        else real(step))
    data = measured(tmp_path, {"joint_damping": {"value": 0.4}})
    cfg = replace(FAST, finest="shared", candidates=("joint_damping", "joint_friction", "armature"),
                  auto_alternatives=0)
    d = diagnose(data, Model.parse("mujoco"), cfg, automatic=True)
    assert d.ranking[0].name == "joint_damping", [(c.name, c.score) for c in d.ranking]
    assert d.set_aside == {"joint_damping": "refused for the test"}
    assert "joint_damping" not in [a.name for a in d.added]
    assert d.added, "the runner-up was not tried"  # damping's effect is partly friction-like
    assert not d.reason.startswith("joint_damping"), d.reason
    assert "joint_damping set aside: refused for the test" in d.reason, d.reason
    assert "set aside by --auto: joint_damping refused for the test" in terminal(d)
    assert "--auto: refused for the test" in write_html(d, tmp_path / "report.html").read_text()


def test_an_implausible_finer_fit_gives_way_to_the_coarser_one_it_beat(tmp_path, monkeypatch):
    # Damping per joint type beats one value for every joint on held-out rows. Where its final fit
    # is implausible (fresh draw k 61: a hip damping the pace gait hardly moves ran to the bound),
    # the shared fit is made final instead of setting the effect aside whole. The real rule is
    # replaced by one that refuses the per-type fit, so the path runs on every machine.
    from acn.models.diagnose import add

    data = measured(tmp_path, {"joint_damping": {"value": [0.1, 0.8, 0.4] * 4}})
    cfg = replace(FAST, finest="type")
    problem = prepare(data, Model.parse("mujoco"), cfg)
    rows = problem.sample(problem.held_rows, cfg.judge_rows, salt=4)
    residual = problem.residual_of(Model.parse("mujoco").sim_config(problem.control), rows)
    fit, _ = add.choose_fit(problem, Model.parse("mujoco"), "joint_damping", cfg, rows, residual)
    assert fit.granularity == "type" and not add.implausible(fit), fit.values
    real = add.implausible
    monkeypatch.setattr(add, "implausible", lambda f: "refused for the test" if f.granularity == "type" else real(f))
    fit, judgement = add.choose_fit(problem, Model.parse("mujoco"), "joint_damping", cfg, rows, residual)
    assert fit.granularity == "shared" and judgement.significant, fit.values
    assert 0.1 < float(np.mean(fit.values["value"])) < 0.8, fit.values


def test_a_richer_effect_gives_way_to_a_simpler_one_beside_the_others(tmp_path):
    """Strength 0.85 and friction 0.2 hidden; both PD gains added first (as greedy adding can on
    noisy logs), then friction. Judged again beside friction, the gains give way to the simpler
    motor_strength and the chain is refitted (``add.revisit``)."""
    from acn.models.diagnose.add import revisit
    from acn.models.diagnose.rank import ties_of

    data = measured(tmp_path, {"motor_strength": {"scale": 0.85}, "joint_friction": {"value": 0.2}})
    nominal = Model.parse("mujoco")
    # among the candidates that look like them, one value for every joint (time)
    cfg = replace(FAST, finest="shared", candidates=("pd_gains", "joint_friction", "motor_strength", "joint_damping"))
    d = diagnose(data, nominal, cfg, add=["pd_gains", "joint_friction"])
    assert [a.name for a in d.added] == ["pd_gains", "joint_friction"]
    # the first effect named carries its ties in the first ranking, as --auto's do; the next one, added
    # after it without a ranking, none
    assert d.added[0].ties == ties_of(next(c for c in d.ranking if c.name == "pd_gains"), d.ranking)
    assert d.added[1].ties == []
    # the report reads the gains in the words of the effects they reproduce (Effect.alike)
    assert "while the PD is unsaturated, the same physics as: motor_strength" in terminal(d), terminal(d)
    residual = d.problem.residual_of(nominal.sim_config(d.problem.control), d.judge_rows)
    chain = revisit(d.problem, d.before, cfg, d.judge_rows, residual, d.added)
    assert [a.name for a in chain] == ["motor_strength", "joint_friction"]
    assert all(a.fit.granularity == "shared" for a in (*d.added, *chain))  # --finest shared
    values = {t.name: t.values for t in chain[-1].after.model.effects}
    assert close(values["motor_strength"]["scale"], 0.85, rel=0.05) and close(values["joint_friction"]["value"], 0.2)
    assert chain[-1].after.headline <= 1.1 * d.final.headline  # as good as the richer chain


def test_an_added_effect_no_longer_significant_beside_the_others_is_left_out(tmp_path):
    """Damping 0.5 hidden; the ground's softness added first, then the damping. Judged again beside
    the damping the softness is not significant, and the chain without it predicts as well, so it
    is left out (``add.revisit``); the damping is kept."""
    from acn.models.diagnose.add import revisit

    data = measured(tmp_path, {"joint_damping": {"value": 0.5}})
    nominal = Model.parse("mujoco")
    cfg = replace(FAST, finest="shared", candidates=("ground_softness", "joint_damping"))
    d = diagnose(data, nominal, cfg, add=["ground_softness", "joint_damping"])
    assert [a.name for a in d.added] == ["ground_softness", "joint_damping"]
    residual = d.problem.residual_of(nominal.sim_config(d.problem.control), d.judge_rows)
    chain = revisit(d.problem, d.before, cfg, d.judge_rows, residual, d.added)
    assert [a.name for a in chain] == ["joint_damping"], [(a.name, a.fit.values) for a in d.added]
    assert close(chain[-1].fit.values["value"], 0.5, rel=0.05)


def test_two_effects_one_stood_in_for_are_found_from_another_start(tmp_path):
    """Payload 2 kg and damping 0.4 hidden; both PD gains added alone (as greedy adding did on a
    noisy log: a higher derivative gain is damping, a lower proportional gain sags like a heavier
    trunk). Started from the next candidates instead, a chain with the payload predicts the
    held-out rows and 5-step rollouts clearly better and replaces it (``add.other_starts``)."""
    from acn.models.diagnose.add import other_starts

    data = measured(tmp_path, {"payload": {"mass": 2.0}, "joint_damping": {"value": 0.4}})
    nominal = Model.parse("mujoco")
    # the runner-up only (joint damping here), among the candidates that matter, one value for every joint (time)
    cfg = replace(FAST, auto_alternatives=1, finest="shared",
                  candidates=("pd_gains", "payload", "joint_damping"))
    d = diagnose(data, nominal, cfg, add=["pd_gains"])
    residual = d.problem.residual_of(nominal.sim_config(d.problem.control), d.judge_rows)
    chain, tried = other_starts(d.problem, d.before, cfg, d.judge_rows, residual, d.floor_mse, d.ranking, d.added)
    assert sorted(a.name for a in chain) == ["joint_damping", "payload"], [c.to_json() for c in tried]
    assert [c.kept for c in tried].count(True) == 1 and not tried[0].kept
    kept = next(c for c in tried if c.kept)
    assert kept.versus["z"] >= 2 and kept.versus["longest_horizon_removed"] > 0, kept.to_json()
    values = {t.name: t.values for t in chain[-1].after.model.effects}
    assert close(values["payload"]["mass"], 2.0) and close(values["joint_damping"]["value"], 0.4), values
    # Every chain tried is listed with why it was kept or set aside, where the user reads
    reported = replace(d, added=chain, chains=tried)
    text, page = terminal(reported), write_html(reported, tmp_path / "r.html").read_text()
    assert set(kept.versus["horizons_removed"]) == {5}  # each open-loop horizon compared (FAST: 1 and 5 steps)
    assert "5-step error" in kept.why
    for c in tried:
        assert f"  {c.start}: {c.label}; " in text and c.why in text
        assert f"started with {c.start}: <b>{c.label}</b>" in page


def test_a_chain_replaces_the_kept_one_where_it_predicts_better_at_more_horizons():
    """``add.predicts_better``: significantly better at one step and not worse at the longest
    horizon (as before), or, where the horizons disagree, better at two of them or more, at more
    than worse, and by more than it loses (the product of the error ratios). The first two
    are fresh draws under attitude feedback whose true effects were in the chain set aside before
    this rule; the noise case is a chain that wins the one step alone. A chain of fewer effects
    replaces the kept one where it predicts as well, and ``add.revisit``'s refitted chain
    replaces the greedy one where it predicts no horizon worse."""
    from acn.models.diagnose.add import horizon_votes, predicts_as_well, predicts_better, predicts_no_worse

    def v(one, z, h5, h25):
        return {"one_step_removed": one, "z": z, "longest_horizon_removed": h25, "horizons_removed": {5: h5, 25: h25}}

    limit_and_gains = v(0.063, 7.7, 0.085, -0.059)  # one step and 5 steps better, 25 steps worse
    lag = v(-0.081, -5.9, 0.144, 0.383)             # one step worse, 5 and 25 steps better
    assert horizon_votes(limit_and_gains) == (2, 1) and predicts_better(limit_and_gains)
    assert horizon_votes(lag) == (2, 1) and predicts_better(lag)
    assert predicts_better(v(0.06, 3.0, -0.01, 0.02))          # better at one step, the longest not worse
    noise = v(0.06, 3.0, 0.01, -0.02)                         # one step alone: what fitting the noise gains
    assert horizon_votes(noise) == (1, 0) and not predicts_better(noise)
    assert not predicts_better(v(0.03, 1.5, 0.04, 0.04))       # within every margin
    far_worse = v(0.08, 4.0, 0.10, -0.30)                     # two horizons won, but by less than 25 steps lost
    assert horizon_votes(far_worse) == (2, 1) and not predicts_better(far_worse)
    assert not predicts_better(v(-0.3, -9.0, 0.2, -0.1))       # more lost than won
    assert predicts_better(v(0.0, 0.4, 0.06, 0.06))            # both open-loop horizons, one step even
    extra_lag = v(-0.001, -0.6, 0.021, 0.097)                 # one horizon alone (a chain with an extra lag)
    assert horizon_votes(extra_lag) == (1, 0) and not predicts_better(extra_lag)
    # with fewer effects, predicting as well is enough (add.predicts_as_well): a fresh draw whose kept chain had
    # an actuator lag beside the true delay and PD gains; without it, no horizon worse and the product below 1
    without_lag = v(0.004, 1.5, 0.035, 0.039)
    assert not predicts_better(without_lag) and predicts_as_well(without_lag)
    assert not predicts_as_well(v(0.02, 2.5, 0.03, -0.06))   # 25 steps worse by more than the margin
    assert not predicts_as_well(v(-0.04, -3.0, 0.0, 0.01))   # no horizon worse by a margin, but worse overall
    # add.revisit keeps a refitted chain only where it predicts no horizon worse: a fresh draw (floor friction and
    # a payload 7.8 cm ahead) whose payload, fitted again beside the friction, turned implausible and gave way to
    # motor strength; that chain against the payload's
    strength_for_payload = v(-0.036, -7.3, -0.264, -0.927)
    assert horizon_votes(strength_for_payload) == (0, 2) and not predicts_no_worse(strength_for_payload)
    assert predicts_no_worse(v(-0.01, -1.0, -0.02, 0.01))    # within every margin: the simpler chain is kept


def test_nominal_data_is_none(tmp_path):
    d = diagnose(measured(tmp_path, {}), Model.parse("mujoco"), FAST)
    assert d.verdict == "none", d.reason


def test_pybullet_measurements_with_a_mujoco_model_still_find_the_effect(tmp_path):
    """The simulators' own gap is background; the hidden latency stands out of it."""
    data = measured(tmp_path, {"actuator_latency": {"seconds": 0.02}}, source="pybullet", seconds=3.0)
    d = diagnose(data, Model.parse("mujoco"), FAST)
    assert d.ranking[0].name == "actuator_latency", [(c.name, c.score) for c in d.ranking[:3]]
    assert close(d.ranking[0].fit.values["seconds"], 0.02, rel=0.25)


# The tests of these logs run on one test process (`make test`'s -n 2): the logs are made once.
NOISY_LOGS = pytest.mark.xdist_group("noisy_logs")


@pytest.fixture(scope="module")
def noisy_logs(tmp_path_factory):
    """Logs from code outside acn-collect (other controller, sensor noise), imported with acn-import."""
    from acn.datasets.importer import ImportConfig, import_log

    root = tmp_path_factory.mktemp("logs")
    springs = lambda spec: [j.stiffness.__setitem__(0, 3.0) for j in spec.joints if j.name != "root"]  # noqa: E731
    friction = lambda spec: [setattr(j, "frictionloss", 0.3) for j in spec.joints if j.name != "root"]  # noqa: E731
    out = {}
    for name, spec in {"nominal": LogSpec(noise=1.0, seed=1),
                       "latency": LogSpec(noise=1.0, seed=3, latency_steps=15),
                       "springs": LogSpec(noise=1.0, seed=2, spec_edit=springs),
                       "friction": LogSpec(noise=1.0, seed=4, seconds=10.0, episodes=4, spec_edit=friction)}.items():
        write_log(root / f"{name}.csv", spec)
        out[name], _ = import_log(root / f"{name}.csv", root / name, ImportConfig(50, 60.0, 1.5, 33.5))
    return out


@NOISY_LOGS
def test_noisy_nominal_log_is_none(noisy_logs):
    d = diagnose(load_measurements(noisy_logs["nominal"]), Model.parse("mujoco"), FAST)
    assert d.verdict == "none", d.reason
    assert 0.5 < 1 - d.structured_share <= 1.0  # the error is mostly noise, and the report says so


def test_effects_that_fit_the_noise_in_the_start_states_are_set_aside(tmp_path):
    """A 100 Hz log with sensor noise and no effect, judged one CONTROL step at a time
    (``step_seconds=None``; by default a step is 0.02 s there, two control steps, and the offsets
    remove 8 %, not a third): a dozen encoder offsets lower the one-step error by a third (noisy
    joint readings press the feet into the ground on average), but make the 25-step open-loop
    prediction worse; they are not named, and the verdict is none."""
    from acn.datasets.importer import ImportConfig, import_log
    from acn.models.diagnose.rank import one_step_only

    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=7, control_hz=100, kp=40.0, kd=1.0, seconds=6.0,
                                            episodes=3))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(100, 40.0, 1.0, 33.5))
    cfg = DiagnoseConfig(horizons=(1, 25), compare_rows=300, rollout_starts=60, rank_rows=150, judge_rows=600,
                         fit_rows=200, rank_iterations=2, step_seconds=None)
    d = diagnose(load_measurements(path), Model.parse("mujoco"), cfg)
    offsets = next(c for c in d.ranking if c.name == "encoder_offset")
    assert offsets.judgement.significant and offsets.judgement.removed > 0.2  # what fooled the one-step judge
    assert offsets.longer_gain < 0 and all(one_step_only(c) for c in d.ranking[d.ranking.index(offsets):])  # last
    assert d.verdict == "none" and "encoder_offset improves the one-step prediction only" in d.reason, d.reason


def test_a_robot_lying_on_its_back_without_any_effect_is_none(tmp_path):
    """The open-loop pace gait flips the robot onto its back within 2 s (benchmarks' "nominal
    (pace)" log). With the trunk on the floor, the noise in the measured joints and height decides
    how deep the robot starts in the ground, and encoder offsets of a few mrad remove 40 % of the
    one-step error. Set aside for their size, what they remove is noise: the verdict is none
    (before stop 30: "unexplained", 47 % structured)."""
    from acn.datasets.importer import ImportConfig, import_log
    from acn.models.diagnose.rank import fits_noise_by_size

    write_log(tmp_path / "log.csv", LogSpec(seconds=10.0, episodes=4, seed=708, controller="pace"))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 60.0, 1.5, 33.5))
    d = diagnose(load_measurements(path), Model.parse("mujoco"), FAST)
    small = [c for c in d.ranking if fits_noise_by_size(c)]
    assert small and max(c.judgement.removed for c in small) > 0.2, [(c.name, c.judgement.removed) for c in small]
    assert d.verdict == "none" and "below 3/4 of the smallest realistic" in d.reason, d.reason
    assert d.structured_share < 0.15


@NOISY_LOGS
def test_noisy_log_from_another_controller_finds_the_latency(noisy_logs):
    d = diagnose(load_measurements(noisy_logs["latency"]), Model.parse("mujoco"), FAST, add=["actuator_latency"])
    assert d.ranking[0].name == "actuator_latency" and d.verdict == "effect", d.reason
    assert close(d.added[0].fit.values["seconds"], 0.015, rel=0.15)
    added = d.added[0]  # what is left is the sensor noise (measured: 98 % of the rest explained)
    assert added.judgement.explained(d.floor_mse) >= 0.8 and added.after.headline < added.before.headline


@NOISY_LOGS
def test_the_smallest_effect_a_log_shows_is_where_a_hidden_one_is_named(noisy_logs, tmp_path):
    """``--limits`` on a noisy log without effects: the smallest joint damping ``--auto`` would name.
    The same log (same seed, same noise) written with damping at 2.5x that is named, at 0.3x not.
    Beside PD gains a strength is absorbed by them (the residual is the same: the gains nominal)."""
    from acn.datasets.importer import ImportConfig, import_log
    from acn.models.diagnose.limits import limits, sizes
    from acn.models.diagnose.pipeline import rule_out

    cfg = replace(FAST, candidates=("joint_damping", "motor_strength", "joint_friction", "armature"))
    d = diagnose(load_measurements(noisy_logs["nominal"]), Model.parse("mujoco"), cfg, automatic=True)
    assert d.verdict == "none", d.reason
    (limit,) = rule_out(d, ("joint_damping",))
    assert limit.value is not None and limit.sizes[0] < limit.value <= limit.sizes[-1], limit.to_json()
    assert np.all(np.diff(limit.removed) > 0) and np.all(np.diff(limit.detected.astype(int)) >= 0), limit.to_json()
    assert "could be missed" in terminal(replace(d, limits=[limit]))
    for factor, named in ((2.5, True), (0.3, False)):
        value = factor * limit.value
        damping = lambda spec: [j.damping.__setitem__(0, value) for j in spec.joints if j.name != "root"]  # noqa: E731
        write_log(tmp_path / f"{factor}.csv", LogSpec(noise=1.0, seed=1, spec_edit=damping))
        path, _ = import_log(tmp_path / f"{factor}.csv", tmp_path / f"log{factor}", ImportConfig(50, 60.0, 1.5, 33.5))
        found = diagnose(load_measurements(path), Model.parse("mujoco"), cfg, automatic=True)
        assert (found.verdict == "effect") == named, (value, found.reason)
    # The sizes scanned run from nominal towards the realistic range, within the bounds.
    control = d.problem.control
    below = sizes(get_effect("torque_limit").parameters[0], control)
    assert np.all(np.diff(below) < 0) and below[0] < control.torque_limit and below[-1] >= 1.0, below
    signed = sizes(get_effect("encoder_offset").parameters[0], control)
    assert np.all(signed > 0) and np.isclose(signed[-1], 0.3), signed
    # Beside PD gains (kp and kd free) a motor strength is the same physics: had it been in the
    # robot, the gains would have been fitted to it, so the log cannot show it beside them.
    gains = get_effect("pd_gains")
    beside = d.final.model.with_effect(gains, gains.nominal(control))
    residual = d.problem.residual_of(beside.sim_config(control), d.judge_rows)
    (alone,) = limits(d.problem, d.final.model, d.judge_rows, residual, d.floor_mse, ("motor_strength",))
    (absorbed,) = limits(d.problem, beside, d.judge_rows, residual, d.floor_mse, ("motor_strength",))
    assert alone.shows(0.8) and not absorbed.shows(0.8), (alone.to_json(), absorbed.to_json())


@NOISY_LOGS
def test_one_joint_alone_is_named_where_its_limit_says_and_not_short_of_it(noisy_logs, tmp_path):
    """``--limits-per-joint`` on the noisy log without effects: joint damping on one joint alone.
    The log shows it far less than on every joint alike (one joint's fit must remove 15 % of the
    error where the floor calls it noise); FR_calf's damping is written at twice the grid size
    first shown there (named, per joint, on FR_calf) and at the size below (not named)."""
    from acn.datasets.importer import ImportConfig, import_log
    from acn.models.diagnose.pipeline import rule_out
    from acn.toolkit.robot import URDF_JOINT

    cfg = replace(FAST, candidates=("joint_damping", "motor_strength", "joint_friction", "armature"))
    d = diagnose(load_measurements(noisy_logs["nominal"]), Model.parse("mujoco"), cfg, automatic=True)
    (limit,) = rule_out(d, ("joint_damping",), one_joint=True)
    one, by_joint = limit.one_joint, limit.to_json()["by_joint"]
    assert one is not None and one.joint in JOINT_NAMES and limit.value is not None, limit.to_json()
    shown = [v for v in by_joint.values() if v is not None]
    assert min(shown) > limit.value  # no joint alone shows as little as every joint alike
    # the joint it shows least: unshown where a joint is, else bisected below the largest grid size
    assert (one.value is None) == (len(shown) < len(JOINT_NAMES)), by_joint
    assert one.value is None or (one.shows(max(shown)) and by_joint[one.joint] == max(shown)), one.to_json()
    assert "one joint alone" in terminal(replace(d, limits=[limit]))
    first = by_joint["FR_calf"]
    below = limit.sizes[list(limit.sizes).index(first) - 1]
    for value, named in ((2.0 * first, True), (below, False)):
        damping = lambda spec: spec.joint(URDF_JOINT["FR_calf"]).damping.__setitem__(0, value)  # noqa: E731
        write_log(tmp_path / f"{value}.csv", LogSpec(noise=1.0, seed=1, spec_edit=damping))
        path, _ = import_log(tmp_path / f"{value}.csv", tmp_path / f"log{value}", ImportConfig(50, 60.0, 1.5, 33.5))
        found = diagnose(load_measurements(path), Model.parse("mujoco"), cfg, automatic=True)
        assert (found.verdict == "effect") == named, (value, found.reason)
        if named:
            (added,) = found.added
            fitted = added.fit.values["value"]
            assert added.name == "joint_damping" and np.argmax(fitted) == JOINT_NAMES.index("FR_calf"), fitted


def test_a_closed_loop_controllers_noisy_log_finds_the_damping(tmp_path):
    """A controller that levels the trunk on its measured, noisy roll and pitch (the pace gait,
    which falls open loop, stays upright): the log's actions carry the noise of the states the
    diagnosis starts from. The damping is still named, fitted and removed."""
    from acn.datasets.importer import ImportConfig, import_log

    damping = lambda spec: [j.damping.__setitem__(0, 0.5) for j in spec.joints if j.name != "root"]  # noqa: E731
    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=21, controller="pace", feedback=1.0, spec_edit=damping))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "robot", ImportConfig(50, 60.0, 1.5, 33.5))
    m = load_measurements(path)
    assert (m.state[:, 2] > 0.2).all()   # the feedback keeps it on its feet
    d = diagnose(m, Model.parse("mujoco"), replace(FAST, finest="shared"), add=["joint_damping"])
    assert d.ranking[0].name == "joint_damping" and d.verdict == "effect", d.reason
    assert close(d.added[0].fit.values["value"], 0.5)   # 0.457 here; seeds 22, 23: 0.436, 0.528
    assert d.added[0].judgement.explained(d.floor_mse) >= 0.8


def test_a_torque_controlled_200_hz_noisy_log_finds_the_damping(tmp_path):
    """A controller that runs the PD itself at 200 Hz on its noisy readings and logs torques
    (acn-import --action-mode torque). One diagnosis step is 0.02 s, four control steps: judged
    one 5 ms control step at a time, the trunk's frame, armature and encoder offsets each removed
    55-61 % of the error (they reshape how the start state's noise propagates) against damping's
    38 %, and --auto added offsets first."""
    from acn.datasets.importer import ImportConfig, import_log

    damping = lambda spec: [j.damping.__setitem__(0, 0.5) for j in spec.joints if j.name != "root"]  # noqa: E731
    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=103, control_hz=200, torque_control=True,
                                            spec_edit=damping))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "robot",
                         ImportConfig(200, 60.0, 1.5, 33.5, action_mode="torque"))
    d = diagnose(load_measurements(path), Model.parse("mujoco"), replace(FAST, finest="shared"), add=["joint_damping"])
    assert to_json(d)["step"] == {"control_steps": 4, "seconds": pytest.approx(0.02), "check_horizon": 5}
    assert "one step = 4 control steps (0.02 s" in terminal(d)
    assert d.ranking[0].name == "joint_damping" and d.verdict == "effect", d.reason
    assert close(d.added[0].fit.values["value"], 0.5)
    assert d.added[0].judgement.explained(d.floor_mse) >= 0.8


def test_a_controller_that_switches_gains_by_gait_phase_has_its_damping_found(tmp_path):
    """A controller that sends stance gains (0.5 kp, 1.5 kd) to the legs in stance and the nominal
    ones in swing, with every command: the model's PD runs each row's gains (``hybrid``),
    and the hidden damping is named, fitted and removed. Folded into targets for the imported
    gains at each row's state (before), it came out 0.37 and 0.32 on seeds 31 and 32 (now 0.52,
    0.51) and latency 13.7 / 13.5 ms for 15 (now 14.8 / 15.3)."""
    from acn.datasets.importer import ImportConfig, import_log

    damping = lambda spec: [j.damping.__setitem__(0, 0.5) for j in spec.joints if j.name != "root"]  # noqa: E731
    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=31, stance_gains=(0.5, 1.5), spec_edit=damping))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "robot", ImportConfig(50, 60.0, 1.5, 33.5))
    m = load_measurements(path)
    assert m.control.hybrid and m.action.shape[1] == 60
    d = diagnose(m, Model.parse("mujoco"), replace(FAST, finest="shared"), add=["joint_damping"])
    assert d.ranking[0].name == "joint_damping" and d.verdict == "effect", d.reason
    assert close(d.added[0].fit.values["value"], 0.5, rel=0.1)
    assert d.added[0].judgement.explained(d.floor_mse) >= 0.8


def test_an_mpc_style_controller_that_sends_stance_legs_pure_torques_has_its_latency_found(tmp_path):
    """Stance legs on kp 0 with a torque the controller computes from its noisy readings (as an
    MPC's force plan), swing legs on the PD: the actions carry kp_t, kd_t and the feedforward
    (60 wide), and a 15 ms latency is named and fitted. Folded into targets for the imported
    gains (before) it read 10.0 ms with armature ranked first, and damping 0.5 read 0.16."""
    from acn.datasets.importer import ImportConfig, import_log

    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=31, stance_torque=True, latency_steps=15))
    path, report = import_log(tmp_path / "log.csv", tmp_path / "robot", ImportConfig(50, 60.0, 1.5, 33.5))
    assert report.findings == [] and set(report.hybrid) == {"action_torque", "action_kp", "action_kd"}
    m = load_measurements(path)
    assert m.action.shape[1] == 60 and (m.action[:, 12:24] == 0).any()  # kp 0 on the stance legs
    d = diagnose(m, Model.parse("mujoco"), replace(FAST, finest="shared"), add=["actuator_latency"])
    assert d.ranking[0].name == "actuator_latency" and d.verdict == "effect", d.reason
    assert abs(d.added[0].fit.values["seconds"] - 0.015) < 0.0015
    assert d.added[0].judgement.explained(d.floor_mse) >= 0.8


def test_a_motor_whose_damping_gain_differs_acts_on_the_velocity_target_too(tmp_path):
    """An MIT-style motor runs kd (dq_des - qd): a kd scale multiplies the velocity target's term
    as well as -qd. The model's PD does the same (the velocity target is part of the action), so
    the right kd_scale reproduces a noise-free log with kd 0.6x; stored folded into the
    feedforward (kd dq_des + tau_ff, stop 38) it was scaled on -qd alone, which made that model
    WORSE than the nominal one (median over rows of the largest joint-velocity error: 0.0011
    rad/s now, 0.39 nominal, 0.67 folded) and a diagnosis of such a log `none`."""
    from acn.datasets.importer import ImportConfig, import_log
    from acn.toolkit.resim import Resimulator
    from acn.toolkit.robot import ModelParams

    write_log(tmp_path / "log.csv", LogSpec(seconds=2.0, episodes=1, seed=5, feedforward=True, gains=(1.0, 0.6)))
    m = load_measurements(import_log(tmp_path / "log.csv", tmp_path / "ds", ImportConfig(50, 60.0, 1.5, 33.5))[0])
    assert m.action.shape[1] == 60 and np.abs(m.action[:, 36:48]).max() > 1.0  # velocity targets, rad/s
    rows = np.arange(len(m))
    error = {}
    for kd_scale in (1.0, 0.6):
        with Resimulator("mujoco", replace(m.control, params=ModelParams(kd_scale=kd_scale))) as sim:
            pred = sim.run(m.state[rows], m.action[rows], m.previous_actions(rows, 1))
        e = pred.state[:, 0, SLICES["joint_vel"]] - m.next_state[rows][:, SLICES["joint_vel"]]
        error[kd_scale] = float(np.median(np.abs(e).max(axis=1)))  # a few contact events jump
    assert error[0.6] < 0.005 and error[0.6] < 0.05 * error[1.0], error


def test_a_corrector_moves_a_hybrid_commands_target_and_keeps_its_gains():
    """A corrector of position targets acts on a hybrid command through the target that drives
    its PD (q_des + (kd dq_des + tau_ff) / kp): q_des moves by the correction, kp, kd, the
    velocity target and the feedforward stay."""
    from acn.models.diagnose.problem import corrected

    class Shift:  # a corrector that adds 0.1 rad to every target
        def correct(self, states, actions):
            return actions + 0.1

    states = np.zeros((2, len(STATE_NAMES)))
    u, kp, kd = np.full((2, 12), 0.3), np.full((2, 12), 40.0), np.full((2, 12), 1.0)
    v, tau = np.full((2, 12), 2.0), np.full((2, 12), 4.0)
    out = corrected(Shift(), states, np.hstack([u, kp, kd, v, tau]))
    np.testing.assert_allclose(out, np.hstack([u + 0.1, kp, kd, v, tau]))
    np.testing.assert_allclose(corrected(Shift(), states, u), u + 0.1)  # plain targets as before


def test_a_controller_with_gains_per_joint_type_is_imported_with_them(tmp_path, capsys):
    """Many controllers run stiffer hips than calves. acn-import takes the gains per joint type
    (or per joint), the dataset records the 12, and the model runs with them: the log then
    matches it within the noise. Imported with one gain for every joint, the same log is
    predicted 40-50 % worse (seeds 5-7: headline 0.35-0.37 against 0.52-0.53)."""
    from acn.cli import import_main

    kp, kd = (100.0, 80.0, 50.0), (2.0, 1.5, 1.0)
    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=5, kp=kp * 4, kd=kd * 4))
    common = [str(tmp_path / "log.csv"), "--control-hz", "50", "--torque-limit", "33.5"]
    assert import_main([*common, "--out", str(tmp_path / "types"), "--kp", "100,80,50", "--kd", "2,1.5,1"]) == 0
    assert import_main([*common, "--out", str(tmp_path / "one"), "--kp", "60", "--kd", "1.5"]) == 0
    info = json.loads((tmp_path / "types" / "meta" / "info.json").read_text())["acn"]
    assert info["kp"] == list(kp * 4) and info["kd"] == list(kd * 4)
    m = load_measurements(tmp_path / "types")
    assert m.control.kp == kp * 4
    d = diagnose(m, Model.parse("mujoco"), FAST)
    one = diagnose(load_measurements(tmp_path / "one"), Model.parse("mujoco"), FAST)
    assert d.verdict == "none", d.reason
    assert one.before.headline > 1.25 * d.before.headline, (one.before.headline, d.before.headline)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        import_main([*common, "--out", str(tmp_path / "bad"), "--kp", "100,80", "--kd", "1.5"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hip,thigh,calf" in err[0], err


def test_repeated_and_corrupted_readings_leave_the_damping_found(tmp_path):
    """A real log repeats a reading that did not arrive (10 % of the rows here) and has corrupted
    packets (2 % of the rows: one reading off by 30x its noise). The repeats are named by the
    data checks, the steps from or to them are left out, and the damping is still found
    (measured: 0.546 with them left out, 0.599 with them in; 0.513 on the same log without
    repeats)."""
    from acn.datasets.importer import ImportConfig, import_log

    damping = lambda spec: [j.damping.__setitem__(0, 0.5) for j in spec.joints if j.name != "root"]  # noqa: E731
    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=31, stale=0.1, glitches=0.02, spec_edit=damping))
    path, report = import_log(tmp_path / "log.csv", tmp_path / "robot", ImportConfig(50, 60.0, 1.5, 33.5))
    assert [f.check for f in report.findings] == ["repeats"] and "every sensor group" in report.findings[0].message
    m = load_measurements(path)
    problem = prepare(m, Model.parse("mujoco"), FAST)
    start, end = repeated_transitions(m)
    assert 0.1 < (start | end).mean() < 0.3 and not (start | end)[np.r_[problem.fit_rows, problem.held_rows]].any()
    d = diagnose(m, Model.parse("mujoco"), replace(FAST, finest="shared"), add=["joint_damping"])
    assert d.ranking[0].name == "joint_damping" and d.verdict == "effect", d.reason
    assert close(d.added[0].fit.values["value"], 0.5)
    assert "the steps the repeats data check names were left out" in d.reason and "fix the data" not in d.reason


def test_low_pass_filtered_joint_velocities_are_derived_and_the_damping_is_found(tmp_path):
    """A robot that low-passes the joint velocities it logs (10 ms): compared with them, damping
    0.5 was fitted as 0.353 and armature 0.0205 added beside it (the filter's lag reads as
    inertia). The data check names the lag, the diagnosis derives those velocities from the
    joint angles instead (measured: 0.491)."""
    from acn.datasets.importer import ImportConfig, import_log

    damping = lambda spec: [j.damping.__setitem__(0, 0.5) for j in spec.joints if j.name != "root"]  # noqa: E731
    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=31, velocity_filter=0.01, spec_edit=damping))
    path, report = import_log(tmp_path / "log.csv", tmp_path / "robot", ImportConfig(50, 60.0, 1.5, 33.5))
    assert [f.check for f in report.findings] == ["velocity_lag"], report.findings
    assert report.findings[0].channels == tuple(GROUPS["joint_vel"])
    m = load_measurements(path)
    problem = prepare(m, Model.parse("mujoco"), FAST)
    assert set(GROUPS["joint_vel"]) <= set(problem.derived) and not set(problem.derived) & set(GROUPS["base_angvel"])
    cfg = replace(FAST, finest="shared", candidates=("joint_damping", "armature", "joint_friction", "pd_gains"))
    d = diagnose(m, Model.parse("mujoco"), cfg, automatic=True)
    assert [a.name for a in d.added] == ["joint_damping"] and d.verdict == "effect", d.reason
    assert close(d.added[0].fit.values["value"], 0.5)
    assert "velocity_lag data check names were derived from the positions" in d.reason, d.reason
    assert "fix the data" not in d.reason


def test_derived_joint_velocities_start_from_the_models_step(tmp_path):
    """Joint velocities derived from the angles (a 10 ms filter) start each row from those the model
    reaches at t from the state at t - 1 (``Problem.starts``). Noise-free, under the true model
    (armature 0.02), the one-step error of the angles is then less than half of that from central
    differences, which hold the very angle the row is compared with (measured: 0.33x on 4 x 10 s).
    An episode's first row has no step before it and keeps the derived velocities."""
    from acn.datasets.importer import ImportConfig, import_log
    from acn.toolkit.resim import Resimulator

    def armature(spec):
        for j in spec.joints:
            if j.name != "root":
                j.armature = 0.02

    write_log(tmp_path / "log.csv", LogSpec(seconds=2.0, episodes=1, seed=5, velocity_filter=0.01,
                                            spec_edit=armature))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "robot", ImportConfig(50, 60.0, 1.5, 33.5))
    model = Model.parse("mujoco").with_effect(get_effect("armature"), {"value": 0.02})
    problem = prepare(load_measurements(path), model, FAST)
    assert problem.velocities_from_step
    d, config, jp = problem.data, model.sim_config(problem.control), SLICES["joint_pos"]
    rows = problem.fit_rows[d.frame[problem.fit_rows] > 0]
    with Resimulator(problem.backend, config) as sim:
        error = {}
        for name, starts in (("central", d.starts(rows, problem.backend, config)),
                             ("model's step", problem.starts(sim, rows, config))):
            pred = sim.run(starts, problem.actions(rows), d.previous_actions(rows, problem.history)).state[:, -1]
            error[name] = float(np.sqrt(np.mean((d.next_state[rows][:, jp] - pred[:, jp]) ** 2)))
        first = np.flatnonzero(d.frame == 0)
        assert np.array_equal(problem.starts(sim, first, config), d.starts(first, problem.backend, config))
    assert error["model's step"] < 0.5 * error["central"], error


def test_instruments_leave_the_armature_to_least_squares_where_rows_start_from_the_models_step():
    """Where rows start from the model's step (derived joint velocities), the instrumental refit
    solves neither the armature nor, beside a fitted armature, a parameter without joints (a lag);
    elsewhere it solves what it did before."""
    from acn.models.diagnose.fitting import FreeParameters, Together, _instrumented

    def solved(step: bool, *names: str) -> list[bool]:
        free = Together([FreeParameters(get_effect(n), "shared", {}) for n in names])
        return _instrumented(SimpleNamespace(velocities_from_step=step), free).tolist()

    assert solved(False, "armature", "actuator_lag") == [True, True]
    assert solved(True, "armature", "actuator_lag") == [False, False]
    assert solved(True, "armature", "torque_limit") == [False, True]
    assert solved(True, "joint_damping", "armature") == [True, False]
    assert solved(False, "actuator_lag", "armature") == [False, True]
    assert solved(True, "actuator_lag", "armature") == [False, False]


def test_one_weak_motor_is_found_where_a_shared_strength_is_not_significant(tmp_path):
    """One motor (FR_calf) at half strength in a short noisy log: fitted as one strength for
    every joint it removes 4 % of the error (z 2.2), and nothing plausible does; the linear
    noise floor calls the error noise (7 % structured, while the true strengths remove 31 % of
    it). The finer look runs all the same, fits the per-joint candidates per joint, and the weak
    motor is named. Before the finer look fitted single joints (this seed): verdict none; per
    leg the fit is 0.71 for the FR leg (z 2.2)."""
    from acn.datasets.importer import ImportConfig, import_log

    strength = np.ones(12)
    strength[JOINT_NAMES.index("FR_calf")] = 0.5
    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=42, strength=strength))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 60.0, 1.5, 33.5))
    cfg = replace(FAST, candidates=("motor_strength", "joint_damping", "payload", "armature"), auto_alternatives=0)
    d = diagnose(load_measurements(path), Model.parse("mujoco"), cfg, automatic=True)
    first = d.ranking[0]
    assert first.name == "motor_strength" and first.fit.granularity == "joint", (first.name, d.reason)
    assert [a.name for a in d.added] == ["motor_strength"] and d.verdict == "effect", d.reason
    scale = np.asarray(d.added[0].fit.values["scale"])
    assert abs(scale[JOINT_NAMES.index("FR_calf")] - 0.5) < 0.075, scale   # measured 0.516
    assert np.abs(np.delete(scale, JOINT_NAMES.index("FR_calf")) - 1.0).max() < 0.1, scale  # 0.07


def test_one_weak_motor_beside_a_delay_is_found_once_the_delay_is_added(tmp_path):
    """A 20 ms delay and one motor (FR_calf) at half strength in a short noisy log. The delay
    removes most of the error, so the first ranking does not look at joints apart; beside the
    delay a new effect is ranked with one value for every joint, and one strength for all twelve
    was not added: before stop 69, --auto stopped at the delay alone (0.022 s). ``add.greedy``
    now fits the new per-joint candidates per joint before it stops, and the weak motor is named
    (FR_calf 0.511, the others 0.99-1.10). The same log without the weak motor: the delay alone."""
    from acn.datasets.importer import ImportConfig, import_log

    cfg = replace(FAST, candidates=("actuator_latency", "motor_strength", "joint_damping"), auto_alternatives=0)
    calf = JOINT_NAMES.index("FR_calf")
    for weak in (0.5, 1.0):
        strength = np.ones(12)
        strength[calf] = weak
        root = tmp_path / f"strength_{weak}"
        root.mkdir()
        write_log(root / "log.csv", LogSpec(noise=1.0, seed=42, strength=strength, latency_steps=20))
        path, _ = import_log(root / "log.csv", root / "log", ImportConfig(50, 60.0, 1.5, 33.5))
        d = diagnose(load_measurements(path), Model.parse("mujoco"), cfg, automatic=True)
        assert d.ranking[0].name == "actuator_latency", [c.name for c in d.ranking]
        if weak == 1.0:
            assert [a.name for a in d.added] == ["actuator_latency"], d.reason
            continue
        assert [(a.name, a.fit.granularity) for a in d.added] == [("actuator_latency", "shared"),
                                                                  ("motor_strength", "joint")], d.reason
        scale = np.asarray(d.added[1].fit.values["scale"])
        assert abs(scale[calf] - 0.5) < 0.075, scale   # measured 0.511
        assert np.abs(np.delete(scale, calf) - 1.0).max() < 0.15, scale  # 0.098
        assert abs(d.added[0].fit.values["seconds"] - 0.02) < 0.004  # 0.022


def test_three_joint_effects_of_another_model_are_found_with_damping_per_joint_type(tmp_path):
    """A1 models of other code (MuJoCo Menagerie's) drive position actuators without a derivative
    gain and put joint damping 1 (hips) / 2 (thighs, calves) N m s/rad, friction 0.2 N m and
    armature 0.01 kg m^2 in every joint. On such a log, imported with kd 0 (no noise: the
    mechanism, not the noise, is tested), --auto first adds one damping for every joint and
    armature; then damping fitted per joint type beside armature removes half of what is left
    and friction most of the rest, while the noise floor (linear library) calls it all noise.
    Before, an added effect never came back finer and the floor stopped the chain: damping 2.02
    shared + armature per type (hip 0.018), no friction."""
    from acn.datasets.importer import ImportConfig, import_log

    def other_model(spec):
        for j in spec.joints:
            if j.name != "root":
                j.damping[0] = 1.0 if "hip" in j.name else 2.0
                j.frictionloss, j.armature = 0.2, 0.01

    write_log(tmp_path / "log.csv", LogSpec(seed=5, kp=100.0, kd=0.0, spec_edit=other_model))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 100.0, 0.0, 33.5))
    cfg = replace(FAST, candidates=("joint_damping", "joint_friction", "armature", "actuator_latency"),
                  auto_alternatives=0)
    d = diagnose(load_measurements(path), Model.parse("mujoco"), cfg, automatic=True)
    steps = [(a.name, a.refines, a.fit.granularity) for a in d.added]
    assert ("joint_damping", "shared", "type") in steps and d.verdict == "effect", (steps, d.reason)
    final = {t.name: np.asarray(t.values["value"], float) * np.ones(12) for t in d.final.model.effects}
    assert sorted(final) == ["armature", "joint_damping", "joint_friction"], steps
    np.testing.assert_allclose(final["joint_damping"], np.tile([1.0, 2.0, 2.0], 4), atol=0.1)  # 1.04, 2.01, 2.01
    np.testing.assert_allclose(final["joint_friction"], 0.2, atol=0.03)                        # 0.192
    np.testing.assert_allclose(final["armature"], 0.01, atol=0.002)                            # 0.0099-0.0101
    assert "refined joint_damping (shared -> type)" in terminal(d)


def test_a_noisy_log_of_a_motion_capture_body_names_its_frame(tmp_path):
    """A log from other code whose trunk is a motion-capture body 6 cm above the trunk origin,
    tilted, with sensor noise: one-step predictions from its states are wrong in every channel.
    --auto adds base_frame_offset at the body's place, and the error falls."""
    from acn.datasets.importer import ImportConfig, import_log

    marker = (0.02, -0.015, 0.06, 0.02, -0.03)
    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=11, marker=marker))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 60.0, 1.5, 33.5))
    cfg = replace(FAST, candidates=("base_frame_offset", "encoder_offset", "payload", "joint_damping"),
                  auto_alternatives=0)
    d = diagnose(load_measurements(path), Model.parse("mujoco"), cfg, automatic=True)
    assert [a.name for a in d.added][:1] == ["base_frame_offset"], (d.reason, [(c.name, doubt(c)) for c in d.ranking])
    fitted = d.added[0].fit.values
    got = np.array([fitted[k] for k in ("x", "y", "z", "roll", "pitch")])
    np.testing.assert_allclose(got[:3], marker[:3], atol=0.01)   # m
    np.testing.assert_allclose(got[3:], marker[3:], atol=0.005)  # rad
    assert d.verdict == "effect" and d.final.headline < 0.7 * d.before.headline, d.reason


def test_the_jacobian_is_taken_by_central_differences_inside_the_bounds():
    """``central_jacobian``: (r(x + h) - r(x - h)) / 2h, one-sided where a bound cuts the step;
    every point it asks for lies within the bounds, all of them in one batch."""
    from acn.models.diagnose.fitting import FD_STEP, central_jacobian

    asked = []

    def residual(z):  # (n, k) points -> (m, k) residuals; smooth, with curvature
        asked.append(z.copy())
        return np.stack([np.sin(z[0]) + z[1] ** 2, z[0] * z[1], np.exp(z[1])])

    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 0.5])
    x = np.array([0.3, 0.5])  # the second parameter at its upper bound
    jac = central_jacobian(residual, lo, hi)(x.reshape(-1, 1), residual(x.reshape(-1, 1)))
    assert len(asked) == 2 and asked[1].shape == (2, 4)  # the residual at x, then 2 n points at once
    assert np.all(asked[1] >= lo[:, None]) and np.all(asked[1] <= hi[:, None])
    h = FD_STEP
    np.testing.assert_allclose(jac[:, 0], [np.cos(0.3) * np.sin(h) / h, 0.5, 0.0], rtol=1e-12, atol=1e-12)
    # at the upper bound: the backward difference over h
    np.testing.assert_allclose(jac[:, 1], [(0.25 - 0.4 ** 2) / h, 0.3, (np.exp(0.5) - np.exp(0.4)) / h], rtol=1e-12)


@NOISY_LOGS
def test_noisy_joint_readings_do_not_bias_the_fitted_friction(noisy_logs):
    """Least squares from noisy start states over-estimates friction; the instrumental refit does not."""
    from acn.models.diagnose.fitting import fit_effect, instrumental_refit
    from acn.models.diagnose.problem import prepare

    cfg = DiagnoseConfig(horizons=(1,), fit_rows=1500)
    problem = prepare(load_measurements(noisy_logs["friction"]), Model.parse("mujoco"), cfg)
    rows = problem.sample(problem.fit_rows, cfg.fit_rows)
    ls = fit_effect(problem, Model.parse("mujoco"), get_effect("joint_friction"), "shared", rows)
    iv = instrumental_refit(problem, Model.parse("mujoco"), ls, rows)
    ls_value, iv_value = float(np.mean(ls.values["value"])), float(np.mean(iv.values["value"]))
    assert ls_value > 0.33, ls_value  # the bias (measured 0.375 here)
    # Friction's sign of a noisy speed is nonlinear in the noise, which instruments cannot undo
    # entirely (measured 0.347 here; 0.30 on benchmarks/diagnose_cases.py's friction log).
    assert abs(iv_value - 0.3) <= 0.2 * 0.3 and iv_value < ls_value - 0.01, (ls_value, iv_value)
    # An effect without joint parameters fitted on top, the friction refitted beside it, leaves the
    # friction's bias (one step is flat along it); the instruments solve for the friction alone.
    biased = Model.parse("mujoco").with_effect(get_effect("joint_friction"), ls.values)
    delay = fit_effect(problem, biased, get_effect("actuator_latency"), "shared", rows, start={"seconds": 0.0},
                       max_iter=0, refit=("joint_friction",))
    beside = instrumental_refit(problem, biased, delay, rows, refit=("joint_friction",))
    assert delay.names == ["seconds", "joint_friction.value"] and beside.x[0] == delay.x[0], (delay.x, beside.x)
    assert abs(beside.x[1] - 0.3) <= 0.2 * 0.3 and beside.x[1] < delay.x[1] - 0.01, (delay.x, beside.x)


def test_noisy_start_states_do_not_make_a_payload_light(tmp_path):
    """Least squares from noisy start states fits a payload light on a pacing robot (errors in
    variables, through the contact forces); the refit on predictions five steps ahead does not
    (``fitting.multistep_refit``). Where the one-step fit ran into a corner (a light mass far above
    the trunk: implausible), the ranking refits over five steps from the realistic middle
    (``rank.over_steps_from_realistic``) and finds the payload."""
    from acn.datasets.importer import ImportConfig, import_log
    from acn.models.diagnose.fitting import fit_effect, multistep_refit
    from acn.models.diagnose.rank import implausible, over_steps_from_realistic

    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=4809, seconds=10.0, episodes=2, controller="pace",
                                            spec_edit=welded_payload(1.82, [-0.0308, -0.0518, 0.0056])))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 60.0, 1.5, 33.5))
    cfg = DiagnoseConfig(horizons=(1, 5), fit_rows=1500)
    nominal, payload = Model.parse("mujoco"), get_effect("payload")
    problem = prepare(load_measurements(path), nominal, cfg)
    rows = problem.sample(problem.fit_rows, cfg.fit_rows)
    starts = problem.sample(problem.fit_rows, 200)  # the refits' start rows (the diagnosis takes up to 600)
    ls = fit_effect(problem, nominal, payload, "shared", rows)
    ahead = multistep_refit(problem, ls, starts)
    ls_mass, mass = float(ls.values["mass"]), float(ahead.values["mass"])
    assert ls_mass < 0.88 * 1.82, ls_mass  # the bias (measured 1.48 kg here; 1.14 on a 4 x 10 s log)
    assert abs(mass - 1.82) <= 0.15 * 1.82 and mass > ls_mass + 0.1, (ls_mass, mass)  # measured 1.648
    corner = fit_effect(problem, nominal, payload, "shared", starts, max_iter=0,
                        start={"mass": 0.68, "com_x": 0.1, "com_y": -0.1, "com_z": 0.16})
    assert implausible(corner), corner.values
    freed = over_steps_from_realistic(problem, nominal, corner, starts)
    assert not implausible(freed) and abs(float(freed.values["mass"]) - 1.82) <= 0.15 * 1.82, freed.values  # 1.866


@NOISY_LOGS
def test_physics_outside_the_catalogue_is_unexplained(noisy_logs):
    """Joint springs are in no candidate: whatever fits best leaves structure, or needs absurd values."""
    d = diagnose(load_measurements(noisy_logs["springs"]), Model.parse("mujoco"), FAST)
    assert d.verdict == "unexplained", d.reason


def test_cli_writes_json_report_and_model(tmp_path, capsys):
    from acn.cli import diagnose_main

    data_dir = tmp_path / "m"
    record(CollectConfig(source="mujoco", target=None, policy="excite", episodes=2, seconds=2.0, seed=4,
                         hidden_effects=[AppliedEffect(get_effect("motor_strength"), {"scale": np.full(12, 0.8)})]),
           data_dir)
    args = [str(data_dir), "--model", "mujoco", "--add", "motor_strength", "--json", str(tmp_path / "d.json"),
            "--report", str(tmp_path / "r.html"), "--save-model", str(tmp_path / "model.json"),
            "--horizons", "1,5", "--effects", "motor_strength,joint_damping,actuator_latency",
            "--closed-loop", "1", "--closed-loop-seconds", "1"]
    assert diagnose_main(args) == 0
    out = capsys.readouterr().out
    assert "verdict: effect" in out and "motor_strength" in out
    result = json.loads((tmp_path / "d.json").read_text())
    # Closed loop: the robot (re-run with its hidden strength from the answer file) beside the
    # model as given and the model with the fitted effect: the physics closes the gap.
    loop = result["closed_loop"]
    assert list(loop["runs"]) == ["uncorrected", "with effects"]  # no oracles for a robot with hidden effects
    unc, fixed = loop["runs"]["uncorrected"], loop["runs"]["with effects"]
    assert fixed["divergence"] < 0.2 * unc["divergence"], (fixed["divergence"], unc["divergence"])
    assert abs(fixed["eps_transfer"]) < abs(unc["eps_transfer"]), (fixed["eps_transfer"], unc["eps_transfer"])
    assert fixed["versus"]["reference"] == "uncorrected" and fixed["versus"]["reward_gap_closer_by"]["mean"] > 0
    assert loop["robot"]["hidden_effects"][0]["name"] == "motor_strength"
    assert "closed loop, model vs the robot" in out and "with effects" in out
    assert result["verdict"] == "effect" and result["data_checks"] == []  # acn-collect's data are consistent
    assert set(result["error"]) == {"1", "5"} and "joint_vel" in result["error"]["1"]
    assert [r["name"] for r in result["ranking"]][0] == "motor_strength"
    for key in ("name", "params", "free_parameters", "explained", "score"):
        assert key in result["ranking"][0]
    added = result["added"][0]
    assert added["name"] == "motor_strength" and added["headline_after"] < added["headline_before"]
    assert all(p["identified"] for p in added["free_parameters"])
    assert "summary" in result["where"] and "by_joint" in result["where"]
    html = (tmp_path / "r.html").read_text()
    assert "plotly" in html.lower() and "motor_strength" in html and "<script" in html
    assert "Closed loop: the model beside the robot" in html
    model = Model.load(tmp_path / "model.json")  # composes: the saved model is a starting point
    assert model.effects[0].name == "motor_strength"
    assert diagnose_main([str(data_dir), "--model", str(tmp_path / "model.json"), "--horizons", "1",
                          "--effects", "motor_strength,joint_damping", "--json", str(tmp_path / "again.json")]) == 0
    again = json.loads((tmp_path / "again.json").read_text())
    assert again["verdict"] == "none" and again["headline_error"]["before"] < 0.2 * added["headline_before"]


def test_a_log_that_breaks_a_convention_is_diagnosed_with_its_data_checks(tmp_path, capsys, acn):
    """Joint speeds logged in deg/s and imported without a map: acn-import says so, and the
    diagnosis lists it and names it in its reason (a model would explain it as physics)."""
    vel = {f"{j}_vel": (f"{j}_vel", np.pi / 180) for j in JOINT_NAMES}  # written as deg/s, same names
    write_log(tmp_path / "log.csv", LogSpec(seconds=3.0, episodes=2, seed=6, noise=1.0, rename=vel))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "m"), "--control-hz", "50", "--kp", "60",
            "--kd", "1.5", "--torque-limit", "33.5")
    assert r.returncode == 0 and "check (velocities): every joint_vel channel" in r.stdout and "deg/s" in r.stdout
    r = acn("diagnose", str(tmp_path / "m"), "--model", "mujoco", "--horizons", "1", "--effects", "joint_damping",
            "--json", str(tmp_path / "d.json"))
    assert r.returncode == 0, r.stderr
    assert "data check (velocities): every joint_vel channel" in r.stdout
    result = json.loads((tmp_path / "d.json").read_text())
    assert result["data_checks"][0]["channels"][0] == "FR_hip_vel" and "consistency finding" in result["reason"]


@pytest.mark.parametrize("args, message", [
    (["--add", "warp"], "unknown effect"),
    (["--effects", "joint_damping,gravity"], "unknown effect"),
    (["--model", "gazebo"], "neither a backend"),
    (["--horizons", "1,x"], "--horizons"),
    (["--corrector", "c"], "give --closed-loop"),
    (["--finest", "wheel"], "finest must be one of shared, type, leg, joint"),
    (["--step-seconds", "-0.01"], "step_seconds must be a positive number"),
    (["--limits-per-joint", "--explain-corrector", "c"], "separate questions"),
])
def test_cli_bad_input_is_one_line(tmp_path, capsys, args, message):
    from acn.cli import diagnose_main

    data_dir = tmp_path / "m"
    data_dir.mkdir()
    assert diagnose_main([str(data_dir), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_bad_measurements_are_refused(tmp_path, capsys, small_dataset):
    from acn.cli import diagnose_main

    (tmp_path / "model.json").write_text('{"backend": "mujoco", "effectz": []}')
    assert diagnose_main([str(small_dataset), "--model", str(tmp_path / "model.json")]) == 2
    assert "unknown key" in capsys.readouterr().err
    assert diagnose_main([str(tmp_path / "nowhere")]) == 2
    assert "does not exist" in capsys.readouterr().err
    # A closed-loop mistake is refused before the diagnosis runs (seconds, not minutes).
    (tmp_path / "with.json").write_text(json.dumps({"backend": "mujoco", "corrector": str(tmp_path)}))
    assert diagnose_main([str(small_dataset), "--model", str(tmp_path / "with.json"), "--closed-loop", "1",
                          "--corrector", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already has the corrector" in err[0], err
    assert diagnose_main([str(small_dataset), "--side", "target", "--closed-loop", "1"]) == 2
    assert "--side source" in capsys.readouterr().err
    with pytest.raises(UserError, match="no target side"):
        load_measurements(measured_path(tmp_path), side="target")


def measured_path(tmp_path):
    return record(CollectConfig(source="mujoco", target=None, policy="stand", episodes=1, seconds=0.2), tmp_path / "s")


def test_measurements_at_another_rate_or_without_joints_are_one_line_errors(tmp_path, capsys):
    import pyarrow as pa
    import pyarrow.csv as pacsv
    from robot_log import simulate

    from acn.cli import diagnose_main, import_main

    cols = simulate(LogSpec(seconds=0.5, episodes=1))
    pacsv.write_csv(pa.table(cols), tmp_path / "log.csv")
    # Imported as 25 Hz while the log is 50 Hz: every time step is wrong, refused with the rate it looks like.
    assert import_main([str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), "--control-hz", "25", "--kp", "60",
                        "--kd", "1.5", "--torque-limit", "33.5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is --control-hz right?" in err[0] and "looks like 50 Hz" in err[0], err
    assert not (tmp_path / "ds").exists()
    # A dataset whose joint channels are all missing is refused by the diagnosis.
    assert import_main([str(tmp_path / "log.csv"), "--out", str(tmp_path / "ok"), "--control-hz", "50", "--kp", "60",
                        "--kd", "1.5", "--torque-limit", "33.5"]) == 0
    capsys.readouterr()
    assert diagnose_main([str(tmp_path / "ok"), "--closed-loop", "1", "--horizons", "1", "--effects", "armature"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not an acn-collect dataset" in err[0], err
    info = json.loads((tmp_path / "ok" / "meta" / "info.json").read_text())
    info["acn"]["missing_channels"] = [f"{j}_pos" for j in ("FR_hip", "FR_thigh", "FR_calf", "FL_hip", "FL_thigh",
                                                            "FL_calf", "RR_hip", "RR_thigh", "RR_calf", "RL_hip",
                                                            "RL_thigh", "RL_calf")]
    (tmp_path / "ok" / "meta" / "info.json").write_text(json.dumps(info))
    capsys.readouterr()
    assert diagnose_main([str(tmp_path / "ok")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "joint positions and actions" in err[0], err


def test_parameters_the_data_cannot_pin_down_are_flagged():
    """A standard error above half the largest realistic magnitude: not identified (0.15 rad for offsets)."""
    from acn.models.diagnose.fitting import EffectFit
    from acn.models.diagnose.rank import unidentified
    from acn.toolkit.state import JOINT_NAMES

    effect = get_effect("encoder_offset")
    stderr = np.full(12, 0.004)
    stderr[:3] = [0.16, 0.36, np.inf]  # e.g. a leg in the air most of the time
    fit = EffectFit(effect, "joint", {"value": np.zeros(12)}, [f"value[{j}]" for j in JOINT_NAMES], np.zeros(12),
                    stderr, Model("mujoco"), cost=0.0, evaluations=0, nominal={"value": np.zeros(12)})
    assert unidentified(fit) == ["value[FR_hip]", "value[FR_thigh]", "value[FR_calf]"]


def test_standard_errors_count_rows_that_share_their_errors():
    """Residuals correlated over consecutive rows (AR(1), 0.8 per row) on a slowly varying regressor:
    the block sandwich's standard error follows the spread of the estimate over 200 draws; the
    one that treats every residual as independent (``mujoco.sysid.calculate_intervals``) is
    less than half of it."""
    from mujoco import sysid
    from scipy.signal import lfilter
    from scipy.special import stdtrit

    from acn.models.diagnose.fitting import _stderr

    rng = np.random.default_rng(0)
    rows, channels = 1000, 3

    def correlated(rho: float) -> np.ndarray:  # unit variance, along the rows of each channel
        e = rng.normal(size=(rows, channels)) * np.sqrt(1 - rho ** 2)
        return lfilter([1.0], [1.0, -rho], e, axis=0).ravel()

    estimates, blocks, independent = [], [], []
    for _ in range(200):
        x = correlated(0.9)
        y = 2.0 * x + correlated(0.8)
        theta = float(x @ y / (x @ x))
        r, jac = (y - theta * x) / np.sqrt(rows), -x[:, None] / np.sqrt(rows)  # as ``Objective`` scales them
        estimates.append(theta)
        blocks.append(_stderr(r, jac, rows)[0])
        independent.append(sysid.calculate_intervals([r], jac)[1][0] / stdtrit(r.size - 1, 0.975))
    spread = float(np.std(estimates))
    assert 0.7 * spread < np.mean(blocks) < 1.3 * spread, (spread, np.mean(blocks))
    assert np.mean(independent) < 0.5 * spread, (spread, np.mean(independent))


def ranked_candidate(rng: np.random.Generator, name: str, value: float, error: float, longer: float | None):
    """A significant candidate whose every parameter is ``value`` and whose held-out residuals
    (600 rows x 4 channels) have spread ``error``; ``longer``: its longest-horizon gain."""
    from acn.models.diagnose.fitting import EffectFit
    from acn.models.diagnose.rank import Candidate, Judgement

    effect = get_effect(name)
    values = {p.name: np.asarray(value) for p in effect.parameters}
    fit = EffectFit(effect, "shared", values, list(values), np.full(len(values), value), np.zeros(len(values)),
                    Model("mujoco"), cost=0.0, evaluations=0, nominal={p.name: p.nominal for p in effect.parameters})
    residual = rng.normal(0.0, error, (600, 4))
    mse = float(np.mean(residual ** 2))
    return Candidate(fit, Judgement(1.0, mse, 1.0 - mse, 10.0, True, residual), 1.0 - mse, longer)


def test_candidates_one_step_cannot_tell_apart_are_ordered_by_the_longer_prediction():
    """Tied at one step (z < 2 between them), the one that lowers the longest-horizon error by
    5 % more goes first; a clear one-step winner, a richer effect no better at one step or a small
    longer gain do not move. A richer effect behind only by its price is tied too, unless it
    reproduces the best."""
    from acn.models.diagnose.rank import prefer_longer, tied_with_best

    rng = np.random.default_rng(0)
    candidate = lambda *args: ranked_candidate(rng, *args)  # noqa: E731

    friction = candidate("joint_friction", 0.45, 0.500, 0.61)
    damping = candidate("joint_damping", 0.5, 0.501, 0.71)   # as good at one step, clearly better at 25 steps
    assert [c.name for c in tied_with_best([friction, damping])] == ["joint_friction", "joint_damping"]
    assert [c.name for c in prefer_longer([friction, damping])] == ["joint_damping", "joint_friction"]
    damping.longer_gain = 0.64                                # better by less than 5 % of the error
    assert [c.name for c in prefer_longer([friction, damping])] == ["joint_friction", "joint_damping"]
    damping.longer_gain = 0.71
    worse = candidate("joint_damping", 0.5, 0.60, 0.71)      # clearly worse at one step: not tied
    assert tied_with_best([friction, worse]) == [] and prefer_longer([friction, worse])[0] is friction
    gains = candidate("pd_gains", 1.3, 0.501, 0.9)           # more parameters, no better at one step: not tied
    assert prefer_longer([friction, gains])[0] is friction
    # More parameters, removing as much at one step, behind only by their price (fresh draw 7: a
    # payload behind motor strength after a torque limit): tied, and first if clearly further ...
    strength = candidate("motor_strength", 0.9, 0.500, 0.41)
    payload = candidate("payload", 0.0, 0.500, 0.50)
    payload.judgement = replace(payload.judgement, removed=strength.judgement.removed)
    assert [c.name for c in tied_with_best([strength, payload])] == ["motor_strength", "payload"]
    assert prefer_longer([strength, payload])[0] is payload
    payload.longer_gain = 0.45                                # within 5 %: the simpler one stays first
    assert prefer_longer([strength, payload])[0] is strength
    # ... but not where the richer one reproduces the best (both PD gains scaled alike are strength)
    gains = candidate("pd_gains", 0.9, 0.500, 0.50)
    gains.judgement = replace(gains.judgement, removed=strength.judgement.removed + 0.01)
    assert tied_with_best([strength, gains]) == [] and prefer_longer([strength, gains])[0] is strength


def test_an_added_effect_names_the_candidates_one_step_could_not_tell_it_from():
    """``rank.tied_either_way`` of the candidate ``--auto`` adds: of the same ranking, those the
    held-out one step does not put behind it, or behind which it would not be put; the report lists
    them under the added effect (terminal, HTML and JSON ``one_step_ties``) with their own fitted
    values and both horizons' shares, the added one first. An added effect's parameters are printed
    apart from those of effects refitted with it."""
    from acn.models.diagnose.add import Added
    from acn.models.diagnose.rank import ties_of, tied_either_way, tied_with
    from acn.models.diagnose.report import _notes, _params_text, _ties_json

    rng = np.random.default_rng(3)
    payload = ranked_candidate(rng, "payload", 0.0, 0.500, 0.71)
    strength = ranked_candidate(rng, "motor_strength", 0.9, 0.501, 0.41)  # as good at one step
    friction = ranked_candidate(rng, "joint_friction", 0.3, 0.60, None)   # clearly worse: not tied
    assert tied_with(payload, [payload, strength, friction]) == [strength]
    # a payload put first by the longer prediction, one step significantly better than strength (z > 2):
    # tied from strength's side only, and the report's ties hold it either way round
    clear = ranked_candidate(rng, "payload", 0.0, 0.47, 0.71)
    clear.score = strength.score - 0.01  # behind strength by the price of its parameters
    assert tied_with(clear, [clear, strength]) == [] and tied_with(strength, [strength, clear]) == [clear]
    assert tied_either_way(clear, [clear, strength, friction]) == [strength]
    assert ties_of(clear, [clear, strength, friction]) == [clear, strength]  # Added.ties: the added one first
    # a chain started past the best (add.other_starts): one as simple and clearly better is ahead, not tied
    assert tied_with(friction, [friction, strength]) == [strength]
    assert tied_either_way(friction, [friction, strength]) == [] and ties_of(friction, [friction, strength]) == []
    before, after = (SimpleNamespace(check=25, channel_error={25: np.full((1, 4), e)}) for e in (1.0, 0.5))
    step = Added(payload.fit, payload.judgement, before, after, [payload, strength])
    said = _notes(step, 1.5)[-1]
    assert said.startswith("the held-out one step could not tell it from motor_strength (scale=0.9) removed ")
    assert f"{strength.judgement.removed:.1%} of the one-step error and 41% of the 25-step one" in said, said
    assert said.endswith(f"(ranked, payload (mass=0, com_x=0, com_y=0, com_z=0) removed "
                         f"{payload.judgement.removed:.1%} of the one-step error and 71% of the 25-step one)"), said
    assert [(t["name"], t["longest_horizon_removed"]) for t in _ties_json(step)] == [("payload", 0.71),
                                                                                     ("motor_strength", 0.41)]
    assert _ties_json(step)[1]["params"] == {"scale": 0.9}
    assert _notes(Added(payload.fit, payload.judgement, before, after), 1.5) == []
    # an effect fitted beside one added before it: its own values, then those refitted with it, apart
    both = replace(strength.fit, names=["scale", "torque_limit.value"], x=np.array([0.9, 13.5]),
                   stderr=np.array([0.003, 0.05]))
    assert _params_text(both) == "scale=0.9 +- 0.003; refitted with it: torque_limit.value=13.5 +- 0.05"


def test_a_richer_effect_that_wins_only_the_one_step_gives_way_to_a_simpler_one():
    """Both PD gains beat joint damping at one step by more than the parsimony margin (as with
    twice the typical sensor noise); damping goes first only if it predicts the longest horizon
    at least as well: extra parameters that buy one-step accuracy alone fit the noise."""
    from acn.models.diagnose.rank import LongestHorizon, prefer_simpler

    rng = np.random.default_rng(1)
    gains = ranked_candidate(rng, "pd_gains", 1.2, 0.40, 0.35)
    damping = ranked_candidate(rng, "joint_damping", 1.2, 0.50, 0.47)
    assert damping.judgement.removed < 0.9 * gains.judgement.removed  # not close at one step
    horizon = LongestHorizon(None, Model("mujoco"), DiagnoseConfig(horizons=(1, 25)))  # both gains known: no rollout
    assert prefer_simpler([gains, damping])[0] is gains                # one step only: the richer one
    assert prefer_simpler([gains, damping], horizon)[0] is damping     # 25 steps: damping as good or better
    damping.longer_gain = 0.30
    assert prefer_simpler([gains, damping], horizon)[0] is gains       # the gains predict 25 steps better too


def test_a_richer_effect_close_at_one_step_keeps_its_place_where_it_predicts_clearly_further():
    """A payload beside a delay (fresh draw 17: 2.9 kg and 19 ms): after the delay, motor strength
    removes 92 % of what the payload removes at one step, the payload predicts significantly better
    (z 4) and lowers the 25-step error by 6 % of it more. Close at one step alone no longer hands
    the place to the simpler effect; a longer gain within 5 % of the simpler one's still does."""
    from acn.models.diagnose.rank import LongestHorizon, paired_z, prefer_simpler

    rng = np.random.default_rng(2)
    payload = ranked_candidate(rng, "payload", 0.0, 0.400, 0.75)
    strength = ranked_candidate(rng, "motor_strength", 0.9, 0.404, 0.69)
    residual = 1.01 * payload.judgement.residual_after  # row by row a little worse: z well above 2
    mse = float(np.mean(residual ** 2))
    strength.judgement = replace(strength.judgement, mse_after=mse, removed=1.0 - mse, residual_after=residual)
    assert strength.judgement.removed >= 0.9 * payload.judgement.removed  # close at one step
    assert paired_z((residual ** 2).mean(1) - (payload.judgement.residual_after ** 2).mean(1)) > 2.0
    horizon = LongestHorizon(None, Model("mujoco"), DiagnoseConfig(horizons=(1, 25)))  # both gains known: no rollout
    assert prefer_simpler([payload, strength])[0] is strength           # one step only: close, the simpler one
    assert prefer_simpler([payload, strength], horizon)[0] is payload   # clearly further: the payload stays
    strength.longer_gain = 0.71
    assert prefer_simpler([payload, strength], horizon)[0] is strength  # within 5 %: the simpler one


def test_what_a_too_small_effect_removes_counts_as_noise():
    """A significant candidate fitted below 3/4 of the smallest realistic magnitude (a 1 mm trunk
    frame: the open-loop pace log whose robot lies on its back, where the noise in the measured
    height decides how deep the trunk starts in the floor) raises the noise floor by what it removes,
    beyond what the best plausible candidate removes; a fit at a bound or one the measurements
    contradict does not (it stands in for another effect: springs fitted as damping)."""
    from acn.models.diagnose.pipeline import noise_fitted
    from acn.models.diagnose.rank import implausible, too_small

    rng = np.random.default_rng(2)
    residual = rng.normal(0.0, 1.0, (600, 4))
    before = np.mean(residual ** 2, axis=0)
    floor = np.full(4, 0.6)
    frame = ranked_candidate(rng, "base_frame_offset", 0.001, 0.9, None)
    springs = ranked_candidate(rng, "joint_damping", 5.0, 0.9, None)
    damping = ranked_candidate(rng, "joint_damping", 0.5, 0.95, 0.4)
    assert too_small(frame.fit) and implausible(springs.fit) and not too_small(springs.fit)
    removed = lambda c: np.clip(before - np.mean(c.judgement.residual_after ** 2, axis=0), 0, None)  # noqa: E731
    np.testing.assert_allclose(noise_fitted(floor, residual, [frame]), floor + removed(frame))
    np.testing.assert_array_equal(noise_fitted(floor, residual, [springs]), floor)
    np.testing.assert_allclose(noise_fitted(floor, residual, [damping, frame]),
                               floor + np.clip(removed(frame) - removed(damping), 0.0, None))
    # Of two noise fits, the larger excess over the plausible candidate counts, not the larger removal:
    # this frame removes more in all (channels 0-1, which damping removes too), the other only in 2-3.
    wide = ranked_candidate(rng, "base_frame_offset", 0.001, 1.0, None)
    wide.judgement.residual_after = residual * np.array([0.6, 0.6, 0.93, 0.93])
    narrow = ranked_candidate(rng, "base_frame_offset", 0.001, 1.0, None)
    narrow.judgement.residual_after = residual * np.array([1.0, 1.0, 0.8, 0.8])
    damping.judgement.residual_after = residual * np.array([0.6, 0.6, 1.0, 1.0])
    assert np.sum(removed(wide)) > np.sum(removed(narrow))
    for fits in ([wide, narrow], [narrow, wide]):
        np.testing.assert_allclose(noise_fitted(floor, residual, [damping, *fits]), floor + removed(narrow))
    frame.judgement.significant = False  # what an insignificant fit removes is not counted
    np.testing.assert_array_equal(noise_fitted(floor, residual, [frame]), floor)
    frame.judgement.significant, frame.fit.contradicted = True, "lifts the stance feet"  # stands in for another
    np.testing.assert_array_equal(noise_fitted(floor, residual, [frame]), floor)


def test_a_small_effect_added_under_sensor_noise_is_named_in_the_verdict():
    """--auto added an effect to a model whose one-step error is mostly noise (< 15 % above the
    floor): the verdict names it (before, it said "none" beside the added effect); with more
    structure left the same addition is "unexplained"; a set-aside best candidate says why."""
    from acn.models.diagnose.add import Added
    from acn.models.diagnose.compare import Comparison
    from acn.models.diagnose.fitting import EffectFit
    from acn.models.diagnose.pipeline import verdict
    from acn.models.diagnose.rank import Candidate, Judgement

    rng = np.random.default_rng(0)

    def fit(name: str, value: float) -> EffectFit:
        effect = get_effect(name)
        values = {p.name: np.asarray(value) for p in effect.parameters}
        return EffectFit(effect, "shared", values, list(values), np.full(len(values), value), np.zeros(len(values)),
                         Model("mujoco"), cost=0.0, evaluations=0, nominal={p.name: p.nominal for p in effect.parameters})

    def comparison(one: float, longest: float) -> Comparison:
        residual = rng.normal(0.0, one, (300, 4))
        return Comparison(Model("mujoco"), {}, {1: np.full(4, one), 25: np.full(4, longest)}, np.arange(300),
                          residual, np.zeros((300, 43)), 0)

    before, after = comparison(0.43, 0.16), comparison(0.424, 0.138)
    mse, mse_after = 0.43 ** 2, 0.424 ** 2
    friction = fit("joint_friction", 0.12)
    judged = Judgement(mse, mse_after, 1 - mse_after / mse, 7.6, True, after.residual)
    added = [Added(friction, judged, before, after)]
    ranking = [Candidate(friction, judged, judged.removed)]
    v, reason, named = verdict(before, mse, 0.89 * mse, ranking, added, automatic=True)
    assert v == "effect" and named == ("joint_friction",), reason
    assert "joint_friction explains" in reason and "25-step open-loop error falls by 26%" in reason
    v, reason, _ = verdict(before, mse, 0.6 * mse, ranking, added, automatic=True)
    assert v == "unexplained", reason
    # 20 % structured before; the effect explains 60 % of it (under the 70 % that names one), but
    # what is left is only 9 % structured: the model with it matches within the noise, as "none" judges
    most = Judgement(mse, 0.88 * mse, 0.12, 7.6, True, after.residual)
    v, reason, named = verdict(before, mse, 0.8 * mse, [Candidate(friction, most, most.removed)],
                               [Added(friction, most, before, after)], automatic=True)
    assert v == "effect" and named == ("joint_friction",), reason
    assert "explains 60%" in reason and "only 9% of the one-step error left" in reason, reason
    offsets = fit("encoder_offset", 1e-4)  # below the smallest realistic offset: set aside
    v, reason, _ = verdict(before, mse, 0.89 * mse, [Candidate(offsets, judged, judged.removed)], [], automatic=True)
    assert v == "none" and "encoder_offset" in reason and "below 3/4 of the smallest realistic" in reason, reason


def test_a_motors_torque_speed_line_is_found_in_a_hopping_robots_log(tmp_path):
    """Another code's DC motor model (Isaac Lab's ``DCMotor``: 33.5 N m stall, 14 rad/s no load)
    on a robot that hops, the one motion of these logs that drives the motors fast and hard at
    once: ``torque_speed`` is ranked first over the whole catalogue, its slope (33.5 / 14 = 2.39
    N m s/rad) fitted and the error removed. (A noise-free log: under the typical sensor noise the
    line bends 1.4 % of this hop's steps, too few to be named; a hop at 1.2x its speed is named,
    docs/diagnosis.md.)"""
    from acn.datasets.importer import ImportConfig, import_log

    write_log(tmp_path / "log.csv", LogSpec(seed=5, controller="hop", dc_motor=(33.5, 14.0)))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "robot", ImportConfig(50, 60.0, 1.5, 33.5))
    d = diagnose(load_measurements(path), Model.parse("mujoco"), replace(FAST, finest="shared"), add=["torque_speed"])
    assert d.ranking[0].name == "torque_speed" and d.verdict == "effect", [(c.name, c.score) for c in d.ranking[:3]]
    assert close(d.added[0].fit.values["slope"], 33.5 / 14.0, 0.1), d.added[0].fit.values
    assert d.added[0].judgement.explained(d.floor_mse) >= 0.8


def test_a_low_pass_on_the_commands_is_told_from_a_latency(tmp_path):
    """Another code's motor follows its (held) commands through a first-order low-pass, 15 ms,
    every physics step: ``actuator_lag`` is ranked first over the whole catalogue, ahead of
    ``actuator_latency`` (which delays the same commands by about as much at low frequency, but
    keeps each control step's jump sharp), under the typical sensor noise; its time constant
    is fitted and the error removed. (Before the catalogue had the lag, such a log was named
    a latency, and a pace log a latency and joint damping.)"""
    from acn.datasets.importer import ImportConfig, import_log

    write_log(tmp_path / "log.csv", LogSpec(seed=6, command_lag=0.015, noise=1.0))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "robot", ImportConfig(50, 60.0, 1.5, 33.5))
    d = diagnose(load_measurements(path), Model.parse("mujoco"), replace(FAST, finest="shared"), add=["actuator_lag"])
    names = [c.name for c in d.ranking]
    assert names[0] == "actuator_lag" and d.verdict == "effect", [(c.name, c.score) for c in d.ranking[:3]]
    assert close(d.added[0].fit.values["timeconst"], 0.015, 0.15), d.added[0].fit.values
    assert d.added[0].judgement.explained(d.floor_mse) >= 0.8


def test_an_effect_that_acts_on_few_steps_is_significant_by_its_longest_horizon_gain():
    """``rank.uneven``: where no plausible candidate is significant at one step, the plausible ones
    that remove >= 2 % or improve it by z >= 3 are checked at the longest horizon, and the one that
    removes most of that error, if a quarter, is significant (a torque limit reached in a few per
    cent of the steps); the verdict says so. Not when another plausible candidate is significant
    at one step (unless it removes under 2 % of the long error), nor below 25 %."""
    from acn.models.diagnose.fitting import EffectFit
    from acn.models.diagnose.pipeline import verdict
    from acn.models.diagnose.rank import Candidate, Judgement, uneven

    residual = np.zeros((10, 4))

    def candidate(name: str, value: float | dict, removed: float, z: float, significant: bool) -> Candidate:
        effect = get_effect(name)
        values = {p.name: np.asarray(value[p.name] if isinstance(value, dict) else value) for p in effect.parameters}
        x = np.array([float(v) for v in values.values()])
        fit = EffectFit(effect, "shared", values, list(values), x, np.zeros(len(values)),
                        Model("mujoco"), cost=0.0, evaluations=0, nominal={p.name: p.nominal for p in effect.parameters})
        j = Judgement(1.0, 1.0 - removed, removed, z, significant, residual)
        return Candidate(fit, j, removed)

    class Horizon:  # the open-loop check with given gains (``LongestHorizon`` simulates them)
        steps = 25

        def __init__(self, gains: dict[int, float]):
            self.gains, self.asked = gains, []

        def gain(self, model) -> float:
            self.asked.append(id(model))
            return self.gains[id(model)]

    def ranking():
        limit = candidate("torque_limit", 19.8, 0.041, 1.3, False)          # plausible, uneven
        offsets = candidate("encoder_offset", 1e-4, 0.064, 6.4, True)      # significant, too small
        damping = candidate("joint_damping", 0.3, 0.01, 2.0, False)        # plausible, removes < 2 %
        return [limit, offsets, damping]

    out = ranking()
    horizon = Horizon({id(out[0].fit.model): 0.48})
    uneven(horizon, out)
    assert out[0].judgement.significant and out[0].judgement.by_longest and out[0].longer_gain == 0.48
    assert horizon.asked == [id(out[0].fit.model)]  # damping removes too little to be checked
    from acn.models.diagnose.compare import Comparison
    before = Comparison(Model("mujoco"), {}, {1: np.full(4, 1.0), 25: np.full(4, 0.5)}, np.arange(10), residual + 1,
                        np.zeros((10, 43)), 0)
    v, reason, named = verdict(before, 1.0, 0.95, out, [], automatic=False)  # the limit explains 82 %
    assert v == "effect" and named == ("torque_limit",), reason
    assert "removes 48% of the longest-horizon open-loop error" in reason and "acts on few steps" in reason

    out = ranking()
    uneven(Horizon({id(out[0].fit.model): 0.2}), out)  # a fifth of the long error: not enough
    assert not out[0].judgement.significant and out[0].longer_gain == 0.2

    out = ranking()
    out[2].judgement.significant = True  # a plausible candidate significant at one step: nothing to check
    horizon = Horizon({})
    uneven(horizon, out)
    assert horizon.asked == [] and not out[0].judgement.significant
    # ... unless it was checked and removes under 2 % of the long error (``short_lived``; a fresh draw: joint
    # friction after the floor's friction, 3.4 % at one step and 0.2 % at 25 steps, beside a 2.2 kg payload)
    out = ranking()
    out[2].judgement.significant, out[2].longer_gain = True, 0.002
    horizon = Horizon({id(out[0].fit.model): 0.48})
    uneven(horizon, out)
    assert out[0].judgement.by_longest and horizon.asked == [id(out[0].fit.model)]

    # clear at one step by z, though below 2 %: checked too, and the one removing most of the long error taken
    # (a fresh draw: a 0.97 kg payload beside an 11 ms delay, motor strength standing in for it first by its price)
    strength = candidate("motor_strength", 0.93, 0.014, 5.6, False)
    payload = candidate("payload", {"mass": 0.75, "com_x": 0.01, "com_y": 0.014, "com_z": 0.059}, 0.018, 8.1, False)
    weak = candidate("joint_friction", 0.2, 0.005, 2.8, False)  # below both thresholds: not checked
    horizon = Horizon({id(strength.fit.model): 0.49, id(payload.fit.model): 0.54})
    uneven(horizon, [strength, payload, weak])
    assert horizon.asked == [id(strength.fit.model), id(payload.fit.model)]
    assert payload.judgement.by_longest and not strength.judgement.significant
    from acn.models.diagnose.pipeline import evidence
    assert evidence(payload) == ("it removes 54% of the longest-horizon open-loop error; at one step only 1.8% "
                                 "(8.1 standard errors): a small effect that adds up")
    # added so, the report says why under the effect
    from acn.models.diagnose.add import Added
    from acn.models.diagnose.report import _notes
    errors = {1: np.full(4, 1.0), 25: np.full(4, 1.0)}
    before = Comparison(Model("mujoco"), {}, errors, np.arange(10), residual + 1, np.zeros((10, 43)), 0)
    after = replace(before, channel_error={1: errors[1], 25: np.full(4, np.sqrt(0.46))})
    step = Added(payload.fit, replace(payload.judgement, significant=False, by_longest=False), before, after)
    assert ("significant by its 25-step prediction: it removes 54% of that open-loop error, 1.8% of the one-step "
            "error (8.1 standard errors, not significant at one step)") in _notes(step, 1.0)
    assert not any("significant by" in t for t in _notes(replace(step, after=before), 1.0))


def _one_row_late(rows: dict) -> dict:
    """``rows`` as a logger that writes the last action sent with the new observation logs them."""
    out = dict(rows)
    for name in (c for c in rows if c.startswith("action")):
        v = np.full(len(rows[name]), np.nan)
        for ep in np.unique(rows["episode_index"]):
            idx = np.flatnonzero(rows["episode_index"] == ep)
            v[idx[1:]] = rows[name][idx[:-1]]
        out[name] = v
    return out


def test_actions_logged_one_row_late_are_named_and_shifted_back_on_import(tmp_path, acn):
    """The model predicts each step far better with the next row's action: the diagnosis names the
    pairing (no physical effect undoes it) and says to fix the data, also where the robot has a
    latency of its own shorter than the control period; imported with --shift-actions 1, and in
    the consistent logs, there is nothing to name."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    from robot_log import simulate

    from acn.models.diagnose.pairing import action_row

    rows = simulate(LogSpec(seconds=4.0, episodes=2, seed=31, noise=1.0))
    pacsv.write_csv(pa.table(rows), str(tmp_path / "log.csv"))
    pacsv.write_csv(pa.table(_one_row_late(rows)), str(tmp_path / "late.csv"))
    control = ["--control-hz", "50", "--kp", "60", "--kd", "1.5", "--torque-limit", "33.5"]
    for name, extra in (("log", []), ("late", []), ("fixed", ["--shift-actions", "1"])):
        log = tmp_path / ("log.csv" if name == "log" else "late.csv")
        assert acn("import", str(log), "--out", str(tmp_path / name), *control, *extra).returncode == 0
    d = diagnose(load_measurements(tmp_path / "late"), Model.parse("mujoco"), FAST)
    assert [f.check for f in d.data_checks] == ["action_row"] and "--shift-actions 1" in d.data_checks[0].message
    assert "fix the data first" in d.reason
    model = Model.parse("mujoco")
    # A robot with a 15 ms latency of its own, logged late: each action acts 5 ms before its row.
    rows = simulate(LogSpec(seconds=4.0, episodes=2, seed=31, noise=1.0, latency_steps=15))
    pacsv.write_csv(pa.table(rows), str(tmp_path / "log15.csv"))
    pacsv.write_csv(pa.table(_one_row_late(rows)), str(tmp_path / "late15.csv"))
    for name in ("log15", "late15"):
        assert acn("import", str(tmp_path / f"{name}.csv"), "--out", str(tmp_path / name), *control).returncode == 0
    for name, named in (("log", False), ("fixed", False), ("log15", False), ("late15", True)):
        problem = prepare(load_measurements(tmp_path / name), model, FAST)
        judge = problem.sample(problem.held_rows, FAST.judge_rows, salt=4)
        residual = problem.residual_of(model.sim_config(problem.control), judge)
        assert (action_row(problem, model, judge, residual) is not None) == named, name


def test_a_log_simulated_at_a_coarser_physics_rate_is_named_and_right_when_imported_at_it(tmp_path, acn):
    """A log from a simulator stepping at 5 ms with stiff gains (its joints chatter), without any
    effect: at the model's 1 kHz no catalogue effect explains it, and the diagnosis names the rate
    (the model's one step is far better at 200 Hz) and says to fix the data; imported with
    --physics-hz 200, and for a log simulated at 1 kHz, there is no rate to name."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    from robot_log import simulate

    from acn.models.diagnose.rate import physics_rate

    pacsv.write_csv(pa.table(simulate(LogSpec(seconds=4.0, episodes=2, seed=31, noise=1.0, physics_hz=200))),
                    str(tmp_path / "coarse.csv"))
    pacsv.write_csv(pa.table(simulate(LogSpec(seconds=4.0, episodes=2, seed=32, noise=1.0))), str(tmp_path / "fine.csv"))
    control = ["--control-hz", "50", "--kp", "60", "--kd", "1.5", "--torque-limit", "33.5"]
    for name, log, extra in (("coarse", "coarse.csv", []), ("at_200", "coarse.csv", ["--physics-hz", "200"]),
                             ("fine", "fine.csv", [])):
        assert acn("import", str(tmp_path / log), "--out", str(tmp_path / name), *control, *extra).returncode == 0
    d = diagnose(load_measurements(tmp_path / "coarse"), Model.parse("mujoco"), FAST)
    rate = [f for f in d.data_checks if f.check == "physics_rate"]  # beside: the chattering joints' velocities
    assert len(rate) == 1 and "--physics-hz 200" in rate[0].message
    assert "fix the data first" in d.reason
    model = Model.parse("mujoco")
    for name in ("at_200", "fine"):
        problem = prepare(load_measurements(tmp_path / name), model, FAST)
        judge = problem.sample(problem.held_rows, FAST.judge_rows, salt=4)
        residual = problem.residual_of(model.sim_config(problem.control), judge)
        ok = np.isfinite(residual).all(1)
        assert physics_rate(problem, model, judge[ok], residual[ok]) is None, name


def test_an_accelerometer_read_at_each_instant_is_recognised_and_compared_so(tmp_path, acn):
    """A log whose accelerometer is MuJoCo's sensor (read at each row's instant, not the
    schema's mean over the control step; the pace gait, whose feet land hard) is recognised from
    the log without a model: integrated against the logged trunk velocity, it gives the
    velocity's change by the trapezoid of two instants (gamma near 1), a mean reading by dt x
    itself (gamma near 0; also against the legs' velocity without motion capture, where the
    model then judges). Where sensor noise leaves the integration undecided the model judges:
    the instant reading predicts better in most rows (measured: 81 %, 49 % of the error). A
    dataset that states its reading (acn-import --imu-acc) is taken at its word. Read so, the
    model with the hidden damping predicts the accelerometer within a few per cent; read as the
    mean, it cannot (measured: 0.022 against 0.64 after the damping is added, noise-free)."""
    from acn.models.diagnose.accelerometer import predicted_better, read_accelerometer

    control = ["--control-hz", "50", "--kp", "60", "--kd", "1.5", "--torque-limit", "33.5"]
    damping = lambda spec: [j.damping.__setitem__(0, 0.5) for j in spec.joints if j.name != "root"]  # noqa: E731
    no_mocap = tuple(GROUPS["base_pos"] + GROUPS["base_linvel"])
    logs = {"sensor": (LogSpec(seed=5, controller="pace", accelerometer="sensor", spec_edit=damping), []),
            "noisy sensor": (LogSpec(noise=1.0, seed=5, controller="pace", accelerometer="sensor"), []),
            "noisy mean": (LogSpec(noise=1.0, seed=5, controller="pace"), []),
            "noisy mean, no mocap": (LogSpec(noise=1.0, seed=5, controller="pace", drop=no_mocap), []),
            "stated": (LogSpec(seed=5, controller="pace", accelerometer="sensor", spec_edit=damping),
                       ["--imu-acc", "mean"])}
    model, read = Model.parse("mujoco"), {}
    for name, (spec, extra) in logs.items():
        write_log(tmp_path / f"{name}.csv", spec)
        r = acn("import", str(tmp_path / f"{name}.csv"), "--out", str(tmp_path / name), *control, *extra)
        assert r.returncode == 0, r.stderr
        problem = prepare(load_measurements(tmp_path / name), model, FAST)
        rows = problem.sample(problem.held_rows, FAST.judge_rows, salt=4)
        read[name] = read_accelerometer(problem, model, rows)
        if name == "sensor":  # the model agrees where it is right and the start states are exact
            assert predicted_better(problem, model, rows).better > 0.85  # measured 0.94
    sensor, noisy = read["sensor"], read["noisy sensor"]
    assert sensor.kind == "instant" and not sensor.by_model and sensor.integration.velocity == "logged", sensor
    assert 0.75 < sensor.integration.gamma < 1.1, sensor  # measured 0.86 +- 0.03
    assert noisy.kind == "instant" and noisy.by_model and noisy.better > 0.7 and noisy.share < 0.8, noisy  # 0.81, 0.49
    assert 0.4 < noisy.integration.gamma < 0.9, noisy  # measured 0.66 +- 0.06: undecided at INTEGRATION_Z
    mean, legs = read["noisy mean"], read["noisy mean, no mocap"]
    assert mean.kind == "mean" and not mean.by_model and abs(mean.integration.gamma) < 0.2, mean  # 0.011 +- 0.023
    # from the legs' velocity only "instant" decides (its bias leans towards the mean): the model reads this one
    assert legs.kind == "mean" and legs.by_model and legs.integration.velocity == "legs'", legs
    assert abs(legs.integration.gamma) < 0.2, legs  # measured 0.021 +- 0.067
    assert read["stated"].kind == "mean" and read["stated"].stated and read["stated"].integration is None
    d = diagnose(load_measurements(tmp_path / "sensor"), model, FAST, add=["joint_damping"])
    assert d.accelerometer.kind == "instant" and "--imu-acc instant" in terminal(d)
    assert d.problem.data.control.imu_acc == "instant"  # what leg odometry would fuse it as
    assert to_json(d)["accelerometer"]["kind"] == "instant"
    assert to_json(d)["accelerometer"]["integration"]["decides"] is True
    assert close(d.added[0].fit.values["value"], 0.5, rel=0.05)
    assert d.final.error[1]["imu_acc"] < 0.1, d.final.error[1]  # measured 0.022
    r = acn("import", str(tmp_path / "sensor.csv"), "--out", str(tmp_path / "bad"), *control, "--imu-acc", "filtered")
    assert r.returncode == 2 and "--imu-acc" in r.stderr


def test_the_legs_velocity_reads_an_instant_accelerometer_and_checks_a_logged_velocity(tmp_path):
    """Without motion capture, the legs' velocity (stance feet at rest, no accelerometer in it)
    shows an accelerometer read at each instant (sines, typical noise, 4 x 10 s; measured gamma
    0.89 +- 0.07). A logged trunk velocity that the robot's own estimator integrated from this
    accelerometer (a complementary filter, v <- 0.9 (v + dt a) + 0.1 v_measured, the reading as if
    it were the mean) integrates it like the mean (0.10 +- 0.01); the legs' contradict it, so the
    model judges, and the report says why."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    from robot_log import simulate

    from acn.datasets.importer import ImportConfig, import_log
    from acn.datasets.odometry import world_acceleration
    from acn.models.diagnose.accelerometer import read_accelerometer
    from acn.toolkit.rotations import rpy_to_matrices

    cols = simulate(LogSpec(seconds=10.0, episodes=4, seed=100, noise=1.0, accelerometer="sensor"))
    rot = rpy_to_matrices(np.stack([cols[n] for n in GROUPS["base_rpy"]], 1))
    world = np.einsum("nij,nj->ni", rot, np.stack([cols[n] for n in GROUPS["base_linvel"]], 1))
    acc = world_acceleration(np.stack([cols[n] for n in GROUPS["imu_acc"]], 1), rot)
    estimate, episode = world.copy(), np.asarray(cols["episode_index"])
    for k in range(1, len(world)):
        if episode[k] == episode[k - 1]:
            estimate[k] = 0.9 * (estimate[k - 1] + 0.02 * acc[k]) + 0.1 * world[k]
    body = np.einsum("nji,nj->ni", rot, estimate)
    logs = {"no mocap": {k: v for k, v in cols.items() if k not in GROUPS["base_pos"] + GROUPS["base_linvel"]},
            "estimator": {**cols, **{n: body[:, i] for i, n in enumerate(GROUPS["base_linvel"])}}}
    model, read = Model.parse("mujoco"), {}
    for name, table in logs.items():
        pacsv.write_csv(pa.table(table), str(tmp_path / f"{name}.csv"))
        path, _ = import_log(tmp_path / f"{name}.csv", tmp_path / name, ImportConfig(50, 60.0, 1.5, 33.5))
        problem = prepare(load_measurements(path), model, FAST)
        read[name] = read_accelerometer(problem, model, problem.sample(problem.held_rows, FAST.judge_rows, salt=4))
    legs, logged = read["no mocap"], read["estimator"]
    assert legs.kind == "instant" and not legs.by_model and legs.integration.velocity == "legs'", legs
    assert legs.integration.gamma > 0.65, legs  # measured 0.89 +- 0.07
    assert "integrated against the legs' velocity" in legs.describe()
    i = logged.integration
    assert logged.by_model and i.velocity == "logged" and i.clear and i.kind == "mean" and i.gamma < 0.3, logged
    assert i.legs.decides and i.legs.kind == "instant", i.legs
    assert "is the logged velocity estimated from this accelerometer?" in logged.describe()


def test_an_instant_accelerometer_a_model_far_from_the_robot_hides_is_read_again_with_the_effects(tmp_path,
                                                                                                monkeypatch):
    """Another model's A1 (kd 0, damping 1 / 2 / 2, friction 0.2, armature 0.01) with MuJoCo's
    accelerometer, noise-free. The integration reads it at each instant without a model (gamma
    near 1). Where the integration could not decide (here: required at an infinite z), the
    nominal model judges, and it is so far from the robot that the instant reading predicts the
    accelerometer no better than the mean (measured: 63 % of the error, better in 49 % of the
    rows): read as the mean. With damping and armature added the instant reading is clearly
    better (6 %, 96 %): the diagnosis runs again reading it so, and says why."""
    from acn.datasets.importer import ImportConfig, import_log
    from acn.models.diagnose import accelerometer

    def other_model(spec):
        for j in spec.joints:
            if j.name != "root":
                j.damping[0] = 1.0 if "hip" in j.name else 2.0
                j.frictionloss, j.armature = 0.2, 0.01

    write_log(tmp_path / "log.csv", LogSpec(seed=5, kp=100.0, kd=0.0, spec_edit=other_model, accelerometer="sensor"))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 100.0, 0.0, 33.5))
    problem = prepare(load_measurements(path), Model.parse("mujoco"), FAST)
    read = accelerometer.read_accelerometer(problem, Model.parse("mujoco"), problem.held_rows[:300])
    assert read.kind == "instant" and not read.by_model and read.integration.gamma > 0.75, read
    monkeypatch.setattr(accelerometer, "INTEGRATION_Z", np.inf)
    said = []
    d = diagnose(load_measurements(path), Model.parse("mujoco"), replace(FAST, finest="shared"),
                 add=["joint_damping", "armature"], progress=lambda msg, fraction=None: said.append(msg))
    assert any("with the effects added the accelerometer reads at each instant" in m for m in said), said
    assert d.accelerometer.kind == "instant" and d.accelerometer.again and d.accelerometer.share < 0.2
    assert "the model with the effects added predicts it better" in terminal(d)
    assert [a.name for a in d.added] == ["joint_damping", "armature"] and d.verdict == "effect", d.reason
    assert d.final.error[1]["imu_acc"] < 0.3, d.final.error[1]  # measured 0.18


def test_auto_holds_an_effect_s_final_fit_to_the_margins_it_asks_of_the_candidate():
    """``too_little``: what ``--auto`` asks of the best candidate, and again of its final fit."""
    from acn.models.diagnose.add import too_little
    from acn.models.diagnose.rank import Judgement

    def judged(after: float) -> Judgement:
        return Judgement(1.0, after, 1.0 - after, 5.0, True, np.zeros((1, 1)))

    assert too_little(judged(0.975), 0.02, floor_mse=0.49) == "explains only 4.9% of the structured error left"
    assert too_little(judged(0.97), 0.02, floor_mse=0.9) == ("removes only 3.0% of the one-step error and 2.0% at "
                                                             "the longest horizon")
    assert too_little(judged(0.97), 0.10, floor_mse=0.9) == ""  # it shows over the longest horizon
    assert too_little(judged(0.6), None, floor_mse=0.1) == ""
