"""Leg odometry: the trunk's position and velocity from the joints, for logs without motion capture.

A real robot rarely measures where its trunk is. An IMU gives the trunk's orientation and
angular velocity and the encoders give the joint angles and speeds; the trunk's position and
linear velocity need motion capture. A simulator must start from a full state, so they are
estimated from the rest, on the assumption that the robot stands on flat ground (the plane
z = 0) on the points of its collision geometry that touch it, and that those points do not
slip:

- the robot is posed with the trunk origin at 0 (orientation ``base_rpy``, joint angles) and
  the lowest point of every collision geom is found (sphere, box, cylinder, capsule exactly;
  other shapes by their bounding box);
- the points that touch: the feet the log flags as touching the ground, else every point
  within ``STANCE_BAND`` of the lowest one (a trotting robot's stance feet; a fallen robot's
  trunk corner or thigh). A flagged foot further above the lowest point than that is not
  taken (a flag that lags a foot's lift-off, as a falling robot's: posed on it, another point
  would start centimetres inside the ground);
- height: ``base_pos_z`` = minus their mean height, lowered by how deep the feet of the model
  that starts from the estimate sink into its ground under the load the accelerometer measures
  (``standing_sink`` x ``Odometry.load``, shared by the feet that carry: a soft contact carries
  the robot's weight a millimetre or two deep; starting it with the feet just touching, its
  contacts would push too little and the trunk would drop: a structured one-step error). That
  depth belongs to the model, not to the log: a model with a softer ground (or a payload) sinks
  deeper, so ``EstimatedHeight`` keeps how each row's height depends on it and a diagnosis
  starts every model it tries at that model's own sink (``EstimatedHeight.starts``; a model
  with encoder offsets on the feet its true joint angles put lowest, one reading the trunk in
  another frame posed by the orientation that frame gives);
- velocity, per sample: each touching point is at rest, so the trunk's world velocity is minus
  the mean velocity those points would have with the trunk origin at rest (joint speeds and
  the trunk's angular velocity, from ``mj_comVel``);
- velocity, along each run of consecutive samples (``smooth_velocity``): those per-sample
  estimates fused with the accelerometer (``imu_acc``), which gives the velocity's change from
  one sample to the next, by a robust fixed-interval smoother; feet slip and drag as they lift
  off, and the accelerometer bridges those samples and flight. Read as the mean specific force
  over each control step (the schema's), it gives that change exactly; read at each sample's
  instant (``SimConfig.imu_acc`` "instant", MuJoCo's sensor), by the trapezoid rule over the
  step's two ends, which misses what a landing foot does between them: so that step's change
  is trusted less, by the trapezoid's error where the acceleration switches between the two
  samples' values at a uniformly distributed moment (``velocity_change``'s spread). Without an
  accelerometer, a robust smoother of the legs' estimates;
- ``base_pos_x``, ``base_pos_y``: the world-frame velocity integrated along each episode from 0
  (on flat ground where the robot stands carries no dynamics).

Measured (``benchmarks/odometry.py``, standing rows, median / 90th percentile): on acn-collect
trot, height 2.5 / 4.5 mm (estimated on a rigid ground: MuJoCo's feet sink that deep, what
``standing_sink`` puts back) and 0.0 / 0.1 mm (PyBullet), velocity 1.6-1.9 /
2.9-3.0 cm/s (spread 28-38 cm/s); on the logs of ``tests/robot_log.py``, whose random
controllers scrape the feet along the ground, with sensor noise, height 2-3 / 5-7 mm, velocity
6-7 / 10-11 cm/s (spread 36-61 cm/s). With MuJoCo's accelerometer on those logs (an instant:
``--accelerometer sensor``), velocity 5.7-6.5 / 9.6-13.9 cm/s without noise and 7.5-8.3 /
12.5-15.5 cm/s with it (sines-pace; without that spread 6.3-6.7 / 11.5-12.6 and 8.1-8.2 /
14.4-15.2: the sines better, the pace's tail 1.3 and 0.3 cm/s worse); fused as if it were the
mean, 7-8 / 15-16 and 9 / 17-18. Estimated channels start the simulator and are never compared
with a prediction.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import mujoco
import numpy as np

from acn.sim.robot import GRAVITY, ModelParams
from acn.sim.rotations import rpy_to_matrices, rpy_to_quat
from acn.sim.state import FOOT_NAMES, GROUPS, SLICES, STATE_NAMES

ACCELEROMETER_NOISE = 0.2  # m/s^2, std of one accelerometer reading (mean over a control step)
LEG_NOISE = 0.1            # m/s, the legs' velocity error the smoother starts from (then estimated)
LEG_NOISE_FLOOR = 0.01     # m/s, the least it is estimated to be (a robot at rest gives exactly 0)
STANCE_BAND = 0.01  # m: without contact flags, points this close to the lowest one touch the ground
SPHERE, CAPSULE, CYLINDER, BOX = (int(t) for t in (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE,
                                                   mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_BOX))


class Odometry:
    """Contact-point odometry on the nominal A1 (one private ``MjData``; not thread-safe)."""

    def __init__(self) -> None:
        from acn.sim.backends import SimConfig
        from acn.sim.backends.mujoco_backend import build_spec
        from acn.sim.robot import TRUNK_LINK, URDF_JOINT
        from acn.sim.state import JOINT_NAMES

        self.model = m = build_spec(SimConfig()).compile()
        self.data = mujoco.MjData(m)
        self.geoms = np.array([g for g in range(m.ngeom) if m.geom_bodyid[g] > 0
                               and (m.geom_contype[g] or m.geom_conaffinity[g])])  # robot collision geoms
        foot_of = {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{f}_foot"): i for i, f in enumerate(FOOT_NAMES)}
        self._is_foot = np.array([g in foot_of for g in self.geoms])
        self._foot_index = np.array([foot_of.get(g, 0) for g in self.geoms])   # the flag read for each geom
        self._qadr = np.array([m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, URDF_JOINT[j])]
                               for j in JOINT_NAMES])
        self._vadr = np.array([m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, URDF_JOINT[j])]
                               for j in JOINT_NAMES])
        self._trunk = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, TRUNK_LINK)
        g = self.geoms
        self._kind = m.geom_type[g][:, None]
        self._size = m.geom_size[g]
        box = self._kind == BOX                               # a box exactly, other shapes by their bounding box
        self._box_centre = np.where(box, 0.0, m.geom_aabb[g, :3])
        self._box_half = np.where(box, m.geom_size[g], m.geom_aabb[g, 3:])

    def lowest_points(self, centre: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """(..., G, 3) world offsets, from the trunk origin, of each collision geom's lowest
        point, given the geoms' centres (..., G, 3) and orientations (..., G, 3, 3) with the
        trunk origin at 0."""
        kind, size = self._kind, self._size
        down = -rot[..., 2, :]                                # world -z in each geom's frame
        axis = np.sign(down[..., 2:3]) * size[:, 1:2] * [0.0, 0.0, 1.0]   # the lower end of a capsule or cylinder
        radial = down * [1.0, 1.0, 0.0]
        radial /= np.maximum(np.linalg.norm(radial, axis=-1, keepdims=True), 1e-9)
        r = size[:, 0:1]
        local = np.where(kind == SPHERE, r * down,
                         np.where(kind == CAPSULE, axis + r * down,
                                  np.where(kind == CYLINDER, axis + r * radial,
                                           self._box_centre + np.sign(down) * self._box_half)))
        return centre + np.einsum("...ij,...j->...i", rot, local)

    def load(self, states: np.ndarray, trunk: np.ndarray) -> np.ndarray:
        """(N,) the ground's vertical force on the robot in units of its weight, from the
        accelerometer (specific force, trunk frame) turned to world axes by ``trunk`` (N, 3, 3):
        the legs move with the trunk to first order. 1 where the accelerometer is not logged."""
        acc = states[:, SLICES["imu_acc"]]
        up = np.einsum("nj,nj->n", trunk[:, 2, :], acc) / np.linalg.norm(self.model.opt.gravity)
        return np.where(np.isfinite(up), np.clip(up, 0.0, None), 1.0)

    def estimate(self, states: np.ndarray, sink: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(height (N,), m; trunk-frame linear velocity (N, 3), m/s; sink share (N,)) of states
        (N, 43) whose ``base_rpy``, ``joint_pos``, ``joint_vel`` and ``base_angvel`` are finite;
        contact flags are used where present (module docstring). ``sink``: how deep the feet of
        the model that will start from these states sink into its ground, standing on four
        (``standing_sink``), m; on fewer points each carries more and sinks deeper in proportion,
        and only feet sink (a trunk resting on the floor sinks 0.06 mm in MuJoCo; with a foot's sink
        per point it started 5 mm deep), and in proportion to the load the accelerometer measures
        (``load``; a foot pushing off carries less than a standing share, a landing more): height =
        height on the surface - sink * share, share = load x 4 x (feet carrying) / (points carrying,
        at least 1)^2, load x 4 / feet where only feet carry it."""
        m, d = self.model, self.data
        n, geoms = len(states), self.geoms
        x, y, z, w = rpy_to_quat(states[:, SLICES["base_rpy"]].T)
        qpos = np.tile(m.qpos0, (n, 1))
        qpos[:, 0:3] = 0.0
        qpos[:, 3:7] = np.stack([w, x, y, z], axis=1)
        qpos[:, self._qadr] = states[:, SLICES["joint_pos"]]
        qvel = np.zeros((n, m.nv))
        qvel[:, 3:6] = states[:, SLICES["base_angvel"]]   # free joint: angular velocity in the trunk frame
        qvel[:, self._vadr] = states[:, SLICES["joint_vel"]]
        centre, rot = np.empty((n, len(geoms), 3)), np.empty((n, len(geoms), 9))
        cvel, com, trunk = np.empty((n, m.nbody, 6)), np.empty((n, 3)), np.empty((n, 9))
        bodies = m.geom_bodyid[geoms]
        for i in range(n):  # with the trunk origin at rest: every body's velocity from the joints and gyro
            d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            centre[i], rot[i], cvel[i] = d.geom_xpos[geoms], d.geom_xmat[geoms], d.cvel
            com[i], trunk[i] = d.subtree_com[self._trunk], d.xmat[self._trunk]
        points = self.lowest_points(centre, rot.reshape(n, -1, 3, 3))                  # (N, G, 3)
        low = points[..., 2]
        weight = np.clip(1.0 - (low - low.min(axis=1, keepdims=True)) / STANCE_BAND, 0.0, 1.0)
        contact = states[:, SLICES["contact"]]
        if not np.isnan(contact).all():
            flags = np.nan_to_num(contact) > 0.5
            flagged = self._is_foot & flags[:, self._foot_index] & (weight > 0)        # (N, G)
            weight = np.where(flagged.any(axis=1, keepdims=True), flagged.astype(float), weight)
        # cvel: (angular, linear) velocity at the robot's centre of mass, world axes
        spin, linear = cvel[:, bodies, :3], cvel[:, bodies, 3:]
        moving = linear + np.cross(spin, points - com[:, None])                          # (N, G, 3) world
        total = weight.sum(axis=1)
        feet = np.sum(weight * self._is_foot, axis=1)
        share = len(FOOT_NAMES) * feet / np.maximum(total, 1.0) ** 2   # only feet sink (see estimate's docstring)
        share = share * self.load(states, trunk.reshape(n, 3, 3))
        height = -np.sum(weight * low, axis=1) / total - sink * share
        world = -np.sum(weight[..., None] * moving, axis=1) / total[:, None]
        return height, np.einsum("nji,nj->ni", trunk.reshape(n, 3, 3), world), share


def smooth_velocity(legs: np.ndarray, change: np.ndarray | None, dt: float,
                    spread: np.ndarray | None = None) -> np.ndarray:
    """(T, 3) world-frame trunk velocities of one run of consecutive samples, m/s, from the legs'
    per-sample estimates ``legs`` (T, 3) and, where the accelerometer is logged, the measured
    change from sample k - 1 to k, ``change`` (T, 3; row 0 unused): per axis, the v minimising

        sum_k (v_k - v_(k-1) - change_k)^2 / q  +  sum_k w_k (legs_k - v_k)^2 / r

    (a tridiagonal system: the fixed-interval Kalman smoother of a random walk driven by the
    accelerometer). q = (dt ACCELEROMETER_NOISE)^2, plus ``spread`` (T, 3; m/s, row 0 unused)
    squared where the change is known less well (``velocity_change``'s spread); without an
    accelerometer the walk is driven by the trunk's unmeasured acceleration, and q comes from the
    legs' own changes d (variance q + 2 r, lag-one covariance -r, clipped at 3 robust standard
    deviations). A slipping foot gives a leg estimate far from the rest, so w_k are Huber
    weights of the residual (1.5 robust standard deviations) and r its robust variance,
    refitted four times."""
    from scipy.linalg import solve_banded

    n = len(legs)
    if n < 3:
        return legs.copy()
    out = np.empty_like(legs)
    for axis in range(3):
        y = legs[:, axis]
        if change is None:  # d = diff(legs): var(d) = q + 2 r, lag-one covariance -r
            u, d = np.zeros(n), np.diff(y)
            scale = 1.4826 * np.median(np.abs(d - np.median(d))) + 1e-12
            d = np.clip(d - np.median(d), -3 * scale, 3 * scale)
            q = np.full(n, max(np.mean(d * d) + 2 * np.mean(d[1:] * d[:-1]), 1e-4 * scale ** 2))
        else:
            u = np.nan_to_num(change[:, axis])
            q = np.full(n, (dt * ACCELEROMETER_NOISE) ** 2)
            if spread is not None:
                q = q + np.nan_to_num(spread[:, axis]) ** 2
        w, r = np.ones(n), LEG_NOISE ** 2
        for _ in range(4):
            bands = np.zeros((3, n))
            bands[0, 1:] = bands[2, :-1] = -1.0 / q[1:]
            bands[1] = w / r + np.r_[0.0, 1.0 / q[1:]] + np.r_[1.0 / q[1:], 0.0]
            rhs = w * y / r + np.r_[0.0, u[1:] / q[1:]] - np.r_[u[1:] / q[1:], 0.0]
            v = solve_banded((1, 1), bands, rhs)
            e = y - v
            sigma = max(1.4826 * np.median(np.abs(e)), LEG_NOISE_FLOOR)
            w, r = np.minimum(1.0, 1.5 * sigma / np.maximum(np.abs(e), 1e-12)), sigma ** 2
        out[:, axis] = v
    return out


@dataclass
class EstimatedHeight:
    """How a log's estimated trunk heights (``base_pos_z`` of its states) depend on the model
    started from them: height = height on the surface - sink * share (``Odometry.estimate``),
    where the surface height comes from the joint angles the model takes the readings for."""

    share: np.ndarray   # (N,) load x 4 x feet / points^2 carrying the robot, per row (``Odometry.estimate``)
    sink: float         # m, the standing sink the heights were estimated for
    columns: tuple[int, ...] = ()   # the state's trunk position and velocity columns estimated (the link's)
    _odometry: Odometry | None = field(default=None, init=False, repr=False, compare=False)

    def subset(self, rows: np.ndarray) -> "EstimatedHeight":
        return EstimatedHeight(self.share[rows], self.sink, self.columns)

    def starts(self, states: np.ndarray, rows: np.ndarray, backend: str, configs: list,
               model: np.ndarray) -> np.ndarray:
        """A copy of ``states`` (rows ``rows`` of the log) with each row's height re-estimated for
        the model ``configs[model[i]]`` (``SimConfig``s of ``backend``) that starts from it: the
        feet as deep as that model's ground and weight sink them standing (``standing_sink``); a
        model that reads the joints with ``encoder_offset`` on the feet its true angles (reading -
        offset) put lowest; a model that reads the trunk in another frame (``base_frame_offset``)
        posed by the trunk's orientation that frame gives, with the estimated trunk position and
        velocity (those of the trunk link) read in that frame, so that the model starts its trunk
        link where the odometry put it (a frame's position offset cannot show without a measured
        position: it is left unidentified, not fitted to 0)."""
        from acn.sim import frames

        out = states.copy()
        z, q, estimated = SLICES["base_pos"].start + 2, SLICES["joint_pos"], list(self.columns)
        for m, config in enumerate(configs):
            sel = np.flatnonzero(model == m)
            if not len(sel):
                continue
            sink = standing_sink(backend, config.params, config.physics_dt)
            offset, frame = config.params.encoder_offset, config.params.base_frame_offset
            if not (np.any(offset != 0.0) or np.any(frame != 0.0)):
                out[sel, z] -= (sink - self.sink) * self.share[rows[sel]]
                continue
            trunk = frames.state_in_trunk(states[sel], frame)   # orientation and gyro of the trunk link
            trunk[:, estimated] = states[np.ix_(sel, estimated)]   # the estimates are the link's already
            trunk[:, q] -= offset
            if self._odometry is None:
                self._odometry = Odometry()
            trunk[:, z] = self._odometry.estimate(trunk, sink)[0]
            trunk[:, q] += offset                               # the model reads the joints with its offsets
            out[sel] = frames.state_in_frame(trunk, frame)
        return out


def standing_sink(backend: str, params=None, physics_dt: float = 0.001) -> float:
    """How deep the A1's feet sink into the ground of ``backend`` standing still on four feet, m
    (nominal soft contacts: MuJoCo 1.3 mm, PyBullet 0.0 mm; a ground of time constant 0.05 s:
    8 mm in both), after 1 s of holding the stance. ``params`` (``ModelParams``, default nominal):
    only what sets the depth counts, the ground and the weight it carries (``ground_timeconst``,
    ``payload_mass``, ``payload_com``); the control law's effects do not change it."""
    params = params or ModelParams()
    com = tuple(float(c) for c in params.payload_com)
    return _standing_sink(backend, physics_dt, params.ground_timeconst, params.payload_mass, com)


@functools.lru_cache(maxsize=4096)
def _standing_sink(backend: str, physics_dt: float, timeconst: float, payload: float,
                   com: tuple[float, ...]) -> float:
    from acn.sim.backends import SimConfig, make_backend
    from acn.sim.backends.base import default_state
    from acn.sim.kinematics import FOOT_RADIUS, RobotKinematics
    from acn.sim.robot import STANCE

    params = ModelParams(payload_mass=payload, payload_com=np.array(com), ground_timeconst=timeconst)
    config = SimConfig(physics_dt=physics_dt, substeps=max(1, int(round(0.02 / physics_dt))), params=params)
    with make_backend(backend, config) as sim:
        sim.reset(default_state())
        for _ in range(int(round(1.0 / config.control_dt))):
            sim.step(STANCE)
        state = sim.get_state()
    feet = RobotKinematics().poses(state[None]).foot[0, :, 2] - FOOT_RADIUS
    return float(max(-feet.mean(), 0.0))


def world_acceleration(specific_force: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """(T, 3) the trunk's world-frame acceleration, m/s^2, from accelerometer readings
    ``specific_force`` (T, 3, trunk frame, gravity included) and trunk-to-world rotations ``rot``."""
    return np.einsum("nij,nj->ni", rot, specific_force) + np.array([0.0, 0.0, -GRAVITY])


def velocity_change(specific_force: np.ndarray, rot: np.ndarray, dt: float,
                    imu_acc: str = "mean") -> tuple[np.ndarray, np.ndarray]:
    """(T, 3) the world-frame trunk velocity's change from sample k - 1 to k (row 0 unused), m/s,
    from the accelerometer's readings ``specific_force`` (T, 3, trunk frame, m/s^2) of a run of
    consecutive samples, ``rot`` (T, 3, 3) their trunk-to-world rotations: dt x (the world
    acceleration of sample k) where each reading is the mean over the step up to it ("mean"), the
    trapezoid rule over the step's two ends where it is read at its instant ("instant").

    And (T, 3) the standard deviation of the change's error beyond the sensor's noise, m/s (its
    spread): 0 for the mean reading (exact); for an instant one, the trapezoid's error where the
    acceleration switches from one sample's value to the next's at a uniformly distributed
    moment of the step, dt |a_k - a_(k-1)| / sqrt(12) (a landing foot between two samples)."""
    world = world_acceleration(specific_force, rot)
    if imu_acc != "instant":
        return dt * world, np.zeros_like(world)
    before = np.vstack([world[:1], world[:-1]])
    return dt * (0.5 * (world + before)), dt * np.abs(world - before) / np.sqrt(12.0)


def fill_trunk(state: np.ndarray, next_state: np.ndarray, linked: np.ndarray, dt: float, missing: list[str],
               sink: float = 0.0, imu_acc: str = "mean") -> tuple[np.ndarray, np.ndarray, list[str],
                                                                  EstimatedHeight | None]:
    """Copies of ``state`` / ``next_state`` (N, 43; row t + 1 follows row t where ``linked[t + 1]``,
    and then starts from row t's next state) with the missing ``base_pos`` and ``base_linvel``
    channels estimated (module docstring), the names of the channels filled, and how the states'
    estimated heights depend on the sink (None where the height was measured). The joint speeds
    and angular velocities must be finite; ``sink`` as in ``Odometry.estimate``; ``imu_acc``: how
    the accelerometer reads (``SimConfig.imu_acc``, ``velocity_change``)."""
    odometry = Odometry()
    state, next_state = state.copy(), next_state.copy()
    velocity = [n for n in GROUPS["base_linvel"] if n in missing]
    z = SLICES["base_pos"].start + 2
    axes = [i for i, n in enumerate(GROUPS["base_linvel"]) if n in velocity]
    cols, acc = [SLICES["base_linvel"].start + i for i in axes], SLICES["imu_acc"]
    has_acc = not np.isnan(state[:, acc]).all()
    if velocity or "base_pos_z" in missing:
        h_now, v_now, share = odometry.estimate(state, sink)
        ends = np.flatnonzero(~np.r_[linked[1:], False])     # rows whose next state no row starts from
        h_next, v_next = np.r_[h_now[1:], 0.0], np.vstack([v_now[1:], np.zeros((1, 3))])
        h_next[ends], v_next[ends], _ = odometry.estimate(next_state[ends], sink)
        if "base_pos_z" in missing:
            state[:, z], next_state[:, z] = h_now, h_next
        if velocity:
            starts = np.flatnonzero(~linked)
            for a, b in zip(starts, np.r_[starts[1:], len(state)] - 1):   # one run of consecutive rows
                samples = np.vstack([state[a:b + 1], next_state[b:b + 1]])
                rot = rpy_to_matrices(samples[:, SLICES["base_rpy"]])
                legs = np.einsum("nij,nj->ni", rot, np.vstack([v_now[a:b + 1], v_next[b:b + 1]]))
                change, spread = velocity_change(samples[:, acc], rot, dt, imu_acc) if has_acc else (None, None)
                body = np.einsum("nji,nj->ni", rot, smooth_velocity(legs, change, dt, spread))
                state[a:b + 1, cols], next_state[a:b + 1, cols] = body[:-1, axes], body[1:, axes]
    planar = [n for n in ("base_pos_x", "base_pos_y") if n in missing]
    if planar:
        def world_velocity(s):
            return np.einsum("nij,nj->ni", rpy_to_matrices(s[:, SLICES["base_rpy"]]), s[:, SLICES["base_linvel"]])

        step = 0.5 * dt * (world_velocity(state) + world_velocity(next_state))   # row t -> its next state
        where = np.zeros((len(state), 3))
        for t in range(1, len(state)):
            if linked[t]:
                where[t] = where[t - 1] + step[t - 1]
        for n in planar:
            k = "xy".index(n[-1])
            state[:, SLICES["base_pos"].start + k] = where[:, k]
            next_state[:, SLICES["base_pos"].start + k] = where[:, k] + step[:, k]
    filled = set(velocity) | set(planar) | ({"base_pos_z"} & set(missing))
    names = [n for n in GROUPS["base_pos"] + GROUPS["base_linvel"] if n in filled]
    height = None
    if "base_pos_z" in filled:
        height = EstimatedHeight(share, sink, tuple(STATE_NAMES.index(n) for n in names))
    return state, next_state, names, height
