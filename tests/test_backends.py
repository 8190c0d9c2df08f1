"""The two simulators behind one interface: state round trip, agreement, walking, faults."""

from __future__ import annotations

import numpy as np
import pytest

from acn.sim import frames
from acn.sim.backends import BACKENDS, SimConfig, SimulationDiverged, default_state, make_backend
from acn.sim.collector import CollectConfig, initial_state
from acn.sim.policies import Trot, make_policy, policy_action
from acn.sim.robot import ModelParams
from acn.sim.state import DYNAMIC_GROUPS, SLICES, STATE_DIM


def random_state(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = default_state()
    s[SLICES["base_pos"]] += rng.uniform(-1, 1, 3) * [1, 1, 0.05]
    s[SLICES["base_rpy"]] = rng.uniform(-0.5, 0.5, 3) * [1, 1, 6]
    s[SLICES["joint_pos"]] += rng.uniform(-0.3, 0.3, 12)
    s[SLICES["base_linvel"]] = rng.normal(size=3)
    s[SLICES["base_angvel"]] = rng.normal(size=3)
    s[SLICES["joint_vel"]] = rng.normal(size=12) * 3
    s[SLICES["contact"]] = rng.integers(0, 2, 4)
    s[SLICES["imu_acc"]] = rng.normal(size=3)
    return s


@pytest.mark.parametrize("name", BACKENDS)
def test_set_state_then_get_state_is_identity(name):
    with make_backend(name) as sim:
        for seed in range(3):
            s = random_state(seed)
            sim.set_state(s)
            np.testing.assert_allclose(sim.get_state(), s, atol=1e-6, rtol=0)


@pytest.mark.parametrize("name", BACKENDS)
def test_the_trunk_read_in_another_frame(name):
    """With ``base_frame_offset`` the state reads the trunk in a frame off the trunk link's (a
    motion-capture body, a tilted IMU): the same simulator state as the formulas of
    acn.sim.frames give, and set_state inverts it exactly; the physics is unchanged."""
    from acn.sim.robot import ModelParams
    from acn.sim.rotations import rpy_to_matrices

    frame = np.array([0.03, -0.02, 0.05, 0.02, -0.04, 0.03])
    d, r_o = frame[:3], rpy_to_matrices(frame[None, 3:])[0]
    s = random_state(1)
    measured = SimConfig(params=ModelParams(base_frame_offset=frame))
    with make_backend(name) as plain, make_backend(name, measured) as framed:
        framed.set_state(s)
        np.testing.assert_allclose(framed.get_state(), s, atol=1e-6, rtol=0)  # set_state inverts the reading
        plain.set_state(s)  # the trunk link at s: what does the frame read?
        rot = rpy_to_matrices(s[None, SLICES["base_rpy"]])[0]
        w, v = s[SLICES["base_angvel"]], s[SLICES["base_linvel"]]
        read = s.copy()
        read[SLICES["base_pos"]] = s[SLICES["base_pos"]] + rot @ d
        read[SLICES["base_rpy"]] = frames.matrices_to_rpy((rot @ r_o)[None])[0]
        read[SLICES["base_angvel"]] = r_o.T @ w
        read[SLICES["base_linvel"]] = r_o.T @ (v + np.cross(w, d))
        framed.set_state(read)
        a = s[SLICES["joint_pos"]] + 0.1
        np.testing.assert_allclose(plain.step(a), framed.step(a), atol=1e-6)  # the same physics: same torques
        after, seen = plain.get_state(), framed.get_state()
        np.testing.assert_allclose(seen[SLICES["joint_vel"]], after[SLICES["joint_vel"]], atol=1e-6)
        rot = rpy_to_matrices(after[None, SLICES["base_rpy"]])[0]
        np.testing.assert_allclose(seen[SLICES["base_pos"]], after[SLICES["base_pos"]] + rot @ d, atol=1e-6)
        np.testing.assert_allclose(seen[SLICES["base_angvel"]], r_o.T @ after[SLICES["base_angvel"]], atol=1e-6)
        np.testing.assert_allclose(seen[SLICES["imu_acc"]], r_o.T @ after[SLICES["imu_acc"]], atol=1e-6)


@pytest.mark.parametrize("name", BACKENDS)
def test_reset_restores_a_fresh_simulator(name):
    """Same initial state and actions give the same trajectory whatever ran before."""
    cfg = CollectConfig()
    s0, policy = initial_state(cfg, 0), Trot()
    with make_backend(name) as sim:
        def run():
            s = sim.reset(s0)
            for k in range(10):
                sim.step(policy(s, k * 0.02))
                s = sim.get_state()
            return s
        first = run()
        sim.reset(random_state(7))
        for _ in range(5):
            sim.step(np.zeros(12))
        np.testing.assert_array_equal(run(), first)


def test_simulators_agree_on_the_first_control_step():
    """From one state with one action the two simulators differ only by their dynamics.

    Tolerances after one 20 ms step of the trot: trunk position 2 mm, orientation 0.01 rad,
    joint angles 0.1 rad, trunk velocity 0.1 m/s (measured: 0.5 mm, 0.003 rad, 0.046 rad,
    0.044 m/s). The gap is real (contact models differ), which is what the toolkit studies.
    """
    cfg = CollectConfig()
    for ep in range(3):
        s0 = initial_state(cfg, ep)
        a = Trot()(s0, 0.0)
        after = []
        for name in BACKENDS:
            with make_backend(name) as sim:
                sim.reset(s0)
                sim.step(a)
                after.append(sim.get_state())
        d = np.abs(after[0] - after[1])
        assert d[SLICES["base_pos"]].max() < 2e-3
        assert d[SLICES["base_rpy"]].max() < 1e-2
        assert d[SLICES["joint_pos"]].max() < 0.1
        assert d[SLICES["base_linvel"]].max() < 0.1
        assert d.max() > 0  # they are different simulators


@pytest.mark.parametrize("name", BACKENDS)
def test_trot_walks_forward_for_ten_seconds(name):
    """>= 0.3 m/s along the trunk's initial heading for 10 s, without falling."""
    from acn.sim.collector import fallen

    policy = Trot()
    with make_backend(name) as sim:
        s = sim.reset()
        for k in range(500):
            sim.step(policy(s, k * 0.02))
            s = sim.get_state()
            assert not fallen(s), f"fell at step {k}"
    assert s[SLICES["base_pos"]][0] / 10.0 >= 0.3


@pytest.mark.parametrize("name", BACKENDS)
def test_torque_mode_applies_the_clipped_torque(name):
    cfg = SimConfig(action_mode="torque", substeps=2, torque_limit=5.0)
    with make_backend(name, cfg) as sim:
        sim.reset()
        a = np.linspace(-10, 10, 12)
        tau = sim.step(a)
        np.testing.assert_allclose(tau, np.clip(a, -5, 5), atol=1e-9)


@pytest.mark.parametrize("name", BACKENDS)
def test_position_mode_torque_is_the_pd_law(name):
    """At rest, the first physics step's torque is exactly kp * (target - q)."""
    cfg = SimConfig(substeps=1)
    with make_backend(name, cfg) as sim:
        s = sim.reset()
        target = s[SLICES["joint_pos"]] + 0.1
        s_joint_vel = s[SLICES["joint_vel"]]
        tau = sim.step(target)
        np.testing.assert_allclose(tau, np.clip(60.0 * 0.1 - 1.5 * s_joint_vel, -33.5, 33.5), atol=1e-5)


@pytest.mark.parametrize("name", BACKENDS)
def test_gains_sent_with_each_command_drive_the_pd(name):
    """With ``hybrid`` an action is (targets, kp, kd, velocity targets, feedforward): at rest the
    first physics step's torque is kp_scale kp_t (target - q) + kd_scale kd_t (v_t - qdot) + tau_t
    with what was sent (kp_t 0: the velocity loop and feedforward alone); sending the config's own
    gains and no velocity target or feedforward every step is the plain PD (same trajectory under
    latency, strength, offsets, gain scales)."""
    kp_t = np.linspace(0.0, 400.0, 12)  # the stiffest joints reach the torque limit
    v_t, tau_t = np.linspace(2.0, -2.0, 12), np.linspace(-3.0, 3.0, 12)
    for kp_scale, kd_scale in ((1.0, 1.0), (0.7, 1.5)):
        with make_backend(name, SimConfig(substeps=1, hybrid=True,
                                          params=ModelParams(kp_scale=kp_scale, kd_scale=kd_scale))) as sim:
            s = sim.reset()
            target = s[SLICES["joint_pos"]] + 0.1
            tau = sim.step(np.concatenate([target, kp_t, np.full(12, 2.0), v_t, tau_t]))
            want = kp_scale * kp_t * 0.1 + kd_scale * 2.0 * (v_t - s[SLICES["joint_vel"]]) + tau_t
            np.testing.assert_allclose(tau, np.clip(want, -33.5, 33.5), atol=1e-5)
            with pytest.raises(ValueError, match=r"\(60,\)"):
                sim.step(target)
    params = ModelParams(latency=0.013, motor_strength=0.8, encoder_offset=0.02, kp_scale=0.7, kd_scale=1.3)
    runs = []
    for gains in (False, True):
        with make_backend(name, SimConfig(params=params, hybrid=gains)) as sim:
            s, trot, states = sim.reset(), Trot(), []
            for k in range(15):
                a = trot(s, 0.02 * k)
                sim.step(np.concatenate([a, np.full(12, 60.0), np.full(12, 1.5), np.zeros(24)]) if gains else a)
                s = sim.get_state()
                states.append(s[:36])
        runs.append(np.array(states))
    np.testing.assert_allclose(runs[1], runs[0], atol=1e-8)
    with pytest.raises(ValueError, match="position mode"):
        SimConfig(action_mode="torque", hybrid=True).validate()


@pytest.mark.parametrize("name", BACKENDS)
def test_blow_up_raises_instead_of_returning_garbage(name):
    cfg = SimConfig(physics_dt=0.01, substeps=2, kp=1e7, kd=0.0, torque_limit=1e9)
    with make_backend(name, cfg) as sim:
        sim.reset()
        with pytest.raises(SimulationDiverged):
            for _ in range(50):
                sim.step(np.zeros(12))


@pytest.mark.parametrize("name", BACKENDS)
def test_bad_action_and_state_are_refused(name):
    with make_backend(name) as sim:
        sim.reset()
        with pytest.raises(ValueError):
            sim.step(np.full(12, np.nan))
        with pytest.raises(ValueError):
            sim.step(np.zeros(11))
        with pytest.raises(ValueError):
            sim.set_state(np.zeros(STATE_DIM - 1))
        bad = default_state()
        bad[SLICES["joint_vel"].start] = np.nan
        with pytest.raises(ValueError):
            sim.set_state(bad)


@pytest.mark.parametrize("name", BACKENDS)
def test_a_state_without_sensor_readings_starts_the_simulator(name):
    """A log without contact flags or accelerometer stores them as NaN: the dynamic channels
    still start the simulator, the step reads the sensors afresh."""
    with make_backend(name) as sim:
        s = random_state(0)
        s[SLICES["contact"]] = np.nan
        s[SLICES["imu_acc"]] = np.nan
        sim.set_state(s)
        np.testing.assert_allclose(sim.get_state()[:SLICES["contact"].start], s[:SLICES["contact"].start], atol=1e-6, rtol=0)
        sim.step(s[SLICES["joint_pos"]])
        assert np.all(np.isfinite(sim.get_state()))


def test_unknown_simulator_and_policy():
    with pytest.raises(ValueError, match="unknown simulator"):
        make_backend("gazebo")
    with pytest.raises(ValueError, match="unknown policy"):
        make_policy("moonwalk")


@pytest.mark.parametrize("policy", ["stand", "excite", "random"])
def test_builtin_policies_keep_the_robot_up(policy):
    p = make_policy(policy)
    p.reset(np.random.default_rng(0))
    with make_backend("mujoco") as sim:
        s = sim.reset()
        targets = []
        for k in range(100):
            a = policy_action(p, s, k * 0.02, sim.config)
            targets.append(a)
            sim.step(a)
            s = sim.get_state()
        assert s[SLICES["base_pos"]][2] > 0.2
    if policy != "stand":  # the signal moves every joint
        assert np.all(np.ptp(np.array(targets), axis=0) > 0.05)


def test_dynamic_channels_cover_everything_a_simulator_integrates():
    assert sum(SLICES[g].stop - SLICES[g].start for g in DYNAMIC_GROUPS) == 36


def test_an_instantaneous_accelerometer_reads_what_mujocos_sensor_reads():
    """``SimConfig.imu_acc`` "instant": the last physics step's specific force, which MuJoCo's
    own ``accelerometer`` sensor at the trunk origin reports; "mean" (the schema's) averages the
    whole control step, and the two differ while the feet hit the ground. Same torques, same
    start (dropped 3 cm), MuJoCo stepped directly with the sensor added to our model."""
    import mujoco

    from acn.sim.backends.mujoco_backend import TRUNK_LINK, build_spec

    s0 = default_state()
    s0[SLICES["base_pos"]][2] += 0.03
    tau = np.tile([0.0, 2.0, -6.0], 4)
    readings = {}
    for kind in ("instant", "mean"):
        with make_backend("mujoco", SimConfig(action_mode="torque", imu_acc=kind)) as sim:
            sim.reset(s0)
            start = sim.data.qpos.copy(), sim.data.qvel.copy()
            rows = []
            for _ in range(8):
                sim.step(tau)
                rows.append(sim.get_state()[SLICES["imu_acc"]])
            readings[kind] = np.array(rows)
    cfg = SimConfig(action_mode="torque")
    spec = build_spec(cfg)
    spec.body(TRUNK_LINK).add_site(name="imu")
    spec.add_sensor(name="acc", type=mujoco.mjtSensor.mjSENS_ACCELEROMETER, objtype=mujoco.mjtObj.mjOBJ_SITE,
                    objname="imu")
    m = spec.compile()
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = start
    d.ctrl[:] = tau
    sensor = []
    for _ in range(8):
        mujoco.mj_step(m, d, nstep=cfg.substeps)
        sensor.append(d.sensor("acc").data.copy())
    sensor = np.array(sensor)
    # the sensor reads at the last step's start pose, 1 ms of rotation earlier (measured: 0.017 m/s^2 at most)
    assert np.abs(readings["instant"] - sensor).max() < 0.05 + 0.01 * np.abs(sensor).max()
    assert np.abs(readings["mean"] - sensor).max() > 5.0  # the landing (measured: 12 m/s^2)
    with pytest.raises(ValueError, match="imu_acc"):
        SimConfig(imu_acc="filtered").validate()


@pytest.mark.parametrize("name", BACKENDS)
def test_the_accelerometer_kind_changes_nothing_but_the_accelerometer(name):
    """An instantaneous accelerometer splits the control step at its last physics step: the
    state, the torque and every other channel stay the same to rounding."""
    s0, trot = initial_state(CollectConfig(), 2), Trot()
    out = {}
    for kind in ("mean", "instant"):
        with make_backend(name, SimConfig(imu_acc=kind)) as sim:
            s, rows = sim.reset(s0), []
            for k in range(10):
                tau = sim.step(trot(s, 0.02 * k))
                s = sim.get_state()
                rows.append(np.concatenate([s, tau]))
            out[kind] = np.array(rows)
    acc = np.r_[SLICES["imu_acc"]]
    other = np.setdiff1d(np.arange(out["mean"].shape[1]), acc)
    np.testing.assert_allclose(out["instant"][:, other], out["mean"][:, other], atol=1e-9)
    assert not np.allclose(out["instant"][:, acc], out["mean"][:, acc])


def test_pybullet_rows_give_the_same_prediction_on_worker_processes_as_here(small_episodes):
    """PyBullet's re-simulation runs in chunks, each in a fresh simulator (its contact solver
    warm-starts from the rows before); the chunks on two worker processes give what they give here."""
    from acn.sim.resim import Resimulator

    source = [e.source for e in small_episodes]
    states = np.concatenate([t.state[:-2] for t in source])
    actions = np.concatenate([np.stack([t.action[i:i + 2] for i in range(len(t.state) - 2)]) for t in source])
    model = np.arange(len(states)) % 3  # three models of one physics: at least three chunks
    here = Resimulator("pybullet", [SimConfig()] * 3, threads=1).run(states, actions, model=model)
    pooled = Resimulator("pybullet", [SimConfig()] * 3, threads=2).run(states, actions, model=model)
    assert np.isfinite(here.state[:, :, SLICES["joint_pos"]]).all()
    for a, b in ((here.state, pooled.state), (here.effort, pooled.effort), (here.diverged, pooled.diverged)):
        assert np.array_equal(a, b, equal_nan=True)
