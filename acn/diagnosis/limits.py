"""What a log can rule out: the smallest size of each catalogue effect the diagnosis would name.

A diagnosis that names nothing, or names one effect and not a second, leaves the question
how large a missed effect could be. For every parameter with a realistic range, of every
catalogue effect the final model does not hold:

- its one-step signature s(m) on the judge rows: the final model's prediction with the effect
  added at ``nominal + m`` (every joint alike, its other parameters nominal) minus without it,
  in the residual's normalised channels, at ``GRID`` sizes m up to ``Thresholds.largest_factor`` x the
  largest realistic magnitude (within the parameter's bounds);
- were the effect in the robot, the measured next states would move by s(m) (to first order:
  the prediction starts from the same measured state), and the final model's residual r would
  be r + s(m); a fit that found the effect exactly would leave r;
- but the final model was fitted to the log: had the effect been in the robot, its effects
  would have moved to explain part of s(m) (PD gains with kp and kd x 0.9 are a motor strength
  of 0.9, to the bit). They move by one Gauss-Newton step (``_Absorbed``): the dz, within their
  bounds, whose change J dz of the residual cancels s(m) best, J the Jacobian in their free
  parameters (central differences at the final values, on the judge rows). The final model
  moved by dz is simulated, and where its residual plus s(m) is smaller than r + s(m), that is
  the would-be residual. J alone is not enough: the one-step residual is not smooth at small
  scales (a 1 % change of both gains moved it 1.9x as far as J says; for that strength J dz
  left 35 % of s, the simulated step 1 %). Absorbing only lowers the would-be error, so it is
  simulated only where it can move the limit (``_absorb``);
- the effect counts as detected at m where that perfect fit passes the rules ``--auto`` adds
  by: ``policy.judge``'s significance (at least ``min_improvement`` of the error, z >= 3 over
  blocks of rows, or ``large_improvement``) and ``policy.too_little`` at one step (explains
  ``auto_min_explained`` of the error above the noise floor, removes ``auto_min_removed``);
- the limit: the smallest such m, the bracket between the grid sizes around it halved
  ``BISECTIONS`` times (the limit is its upper end).

A limit is optimistic: it assumes the fit finds the effect exactly, that nothing stands in for
it beyond what one step of the final model's effects absorbs, and that noise in the measured
start states does not bias its fit (Coulomb friction from a noisy speed fits high: the reason
a small friction is missed beside a larger effect). An effect that the log shows only over
long predictions (a torque limit reached on few steps, ``policy.uneven``) can be found below its
one-step limit. A signed parameter (an offset) is scanned in the + direction only.

One joint alone (``one_joint=True``, ``--limits-per-joint``): a worn gearbox or a weak motor sits
in one joint. Each per-joint parameter is also set on one joint at a time, the other eleven
nominal, at the same sizes; the joint whose limit is largest (the one the log shows least, by
the grid, ties to the smallest share removed) is bisected, and its scan is ``Limit.one_joint``.
That limit holds for every joint: at or beyond it, one joint's effect is shown wherever it
sits. Detected by the same rules, and where the noise floor calls the log's error noise, the
perfect fit must also remove ``structured_share`` of it: ``policy.finer_look``'s rule for a fit
per joint there. The diagnosis looks at one joint alone in its first ranking (where no effect
explains most of the error), at an effect already added, and (``--auto``: ``policy.greedy``) at the
new per-joint candidates beside the added effects before it stops. With ``--add`` alone it does
not: there a limit per joint beside the added effects is a bound the diagnosis may not reach.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from mujoco import minimize

from acn.diagnosis.fitting import FreeParameters, Objective, Together, central_jacobian, granularity_of
from acn.diagnosis.problem import Problem
from acn.diagnosis.policy import THRESHOLDS, Thresholds, judgement, too_little
from acn.sim.effects import Effect, Model, Parameter, get_effect
from acn.sim.state import JOINT_NAMES

GRID = 6         # sizes scanned per parameter: largest_factor x the largest realistic magnitude, halved GRID - 1 times
BISECTIONS = 2   # halvings of the bracket around the limit (in the log of the distance: within a factor 2^(1/4))


@dataclass
class Limit:
    """The smallest size of one parameter of an effect that a log would show (module docstring)."""

    effect: str
    parameter: str
    unit: str
    nominal: float
    sizes: np.ndarray      # (GRID,) values scanned (the parameter's value, not its distance from nominal)
    removed: np.ndarray    # (GRID,) share of the would-be error a perfect fit removes at each
    z: np.ndarray          # (GRID,) its paired z over blocks of rows
    detected: np.ndarray   # (GRID,) whether ``--auto`` would add it there (one step)
    value: float | None    # the limit (a value of the parameter); None where no size scanned is detected
    realistic: tuple[float, float]
    joint: str = ""        # the one joint the effect was set on ("": every joint alike)
    one_joint: Limit | None = None  # every joint alike: the scan on the joint the log shows least (module docstring)
    by_joint: np.ndarray | None = None  # (12,) every joint alike: the smallest grid size shown on each joint alone
    # (nan: not up to the largest), in JOINT_NAMES order

    @property
    def inert(self) -> bool:
        """Whether the parameter alone (the effect's others nominal) changes no prediction (a payload's
        centre of mass without its mass: the share removed is 0 to the last bit of the mean, 2e-16).
        An effect the log does not exercise changes the simulation's rounding (the torque-speed
        slope on a trot: -7e-11 of the error, and +1e-9 on a second fit of the same log) and is
        reported as not shown."""
        return bool(np.all(np.abs(self.removed) <= 1e-12))

    def describe(self) -> str:
        if self.inert:
            return "no effect alone (its other parameters nominal)"
        if self.value is None:
            return f"not shown up to {_short(self.sizes[-1])}{_unit(self.unit)}"
        # shown at the smallest size scanned: perhaps nearer nominal too (below it, or above it for a
        # parameter scanned downwards, such as a strength or a torque limit)
        nearer = ("<= " if self.value > self.nominal else ">= ") if self.detected[0] else ""
        return f"{nearer}{_short(self.value)}{_unit(self.unit)}"

    def realistic_text(self) -> str:
        return f"{_short(self.realistic[0])}..{_short(self.realistic[1])}{_unit(self.unit)}"

    def shows(self, value: float) -> bool:
        """Whether the log would show the effect at ``value``: at the limit or further from nominal."""
        return self.value is not None and abs(value - self.nominal) >= abs(self.value - self.nominal)

    def missable(self) -> str:
        """The part of the realistic range (in distance from nominal) below the limit: what the log could miss."""
        near, far = sorted(self.realistic, key=lambda x: abs(x - self.nominal))
        if self.inert:
            return ""
        if not self.shows(far):
            return "all of it"
        if self.shows(near):
            return "none"
        return "..".join(_short(v) for v in sorted((near, self.value)))

    def to_json(self) -> dict:
        out = {"effect": self.effect, "parameter": self.parameter, "unit": self.unit, "nominal": self.nominal,
               "limit": self.value, "realistic": list(self.realistic), "realistic_missable": self.missable(),
               "inert": self.inert, "sizes": self.sizes.tolist(),
               "removed": self.removed.tolist(), "z": self.z.tolist(), "detected": self.detected.tolist()}
        if self.joint:
            out["joint"] = self.joint
        if self.one_joint is not None:
            out["one_joint"] = self.one_joint.to_json()
            out["by_joint"] = {n: None if np.isnan(v) else float(v) for n, v in zip(JOINT_NAMES, self.by_joint)}
        return out


def _short(v: float) -> str:
    return f"{v:.3g}"


def _unit(unit: str) -> str:
    return "" if unit == "1" else f" {unit}"


def sizes(p: Parameter, control, t: Thresholds = THRESHOLDS) -> np.ndarray:
    """(GRID,) values of ``p`` from near nominal to ``t.largest_factor`` x its largest realistic
    distance from nominal, towards its realistic range (+ for a signed one), within its bounds."""
    nominal = p.nominal_for(control)
    if p.signed:
        direction, largest = 1.0, float(max(p.realistic))
    else:
        far = max(p.realistic, key=lambda x: abs(x - nominal))
        direction, largest = float(np.sign(far - nominal)), abs(far - nominal)
    steps = t.largest_factor * largest * 0.5 ** np.arange(GRID - 1, -1, -1)
    return np.clip(nominal + direction * steps, p.lower, p.upper)


@dataclass
class _Absorbed:
    """What the final model's effects absorb of a signature (module docstring): the Jacobian of its
    one-step residual in their free parameters z (each over its typical magnitude, ``fitting``'s
    units) and how far z may move within their bounds."""

    model: Model
    free: Together
    z0: np.ndarray     # (p,) the final values
    jac: np.ndarray    # (N * C, p) d residual / d z on the judge rows, rows as in ``residual.ravel()``
    lower: np.ndarray  # (p,) the least dz (to the lower bounds)
    upper: np.ndarray  # (p,) the largest dz

    @classmethod
    def by(cls, problem: Problem, model: Model, rows: np.ndarray) -> _Absorbed | None:
        """The Jacobian of ``model``'s effects at their values (None where it holds none)."""
        if not model.effects:
            return None
        free = Together([FreeParameters(t.effect, granularity_of(t.effect, t.values), t.values) for t in model.effects])
        scale = free.scale()
        lo, hi = (b / scale for b in free.bounds())
        z0 = free.start(None) / scale
        jac = central_jacobian(Objective(problem, model, free, rows, budget=np.inf), lo, hi)(z0, None)
        return cls(model, free, z0, jac * np.sqrt(len(rows)), lo - z0, hi - z0)  # the objective divides by sqrt(N)

    def step(self, s: np.ndarray) -> np.ndarray:
        """The Gauss-Newton step dz (p,) whose change of the residual, J dz, cancels ``s`` (N, C)
        best, within the bounds."""
        v = s.ravel()
        dz = np.linalg.lstsq(self.jac, -v, rcond=1e-8)[0]
        if np.any(dz < self.lower) or np.any(dz > self.upper):  # a bound stops them: fit within the box
            jac = self.jac
            dz = minimize.least_squares(np.clip(dz, self.lower, self.upper), lambda z: v[:, None] + jac @ z,
                                        bounds=[self.lower, self.upper], jacobian=lambda z, r: jac,
                                        verbose=0, max_iter=50)[0]
        return dz

    def config(self, dz: np.ndarray, control):
        """The final model's simulator configuration with its effects moved by ``dz``."""
        return self.free.model(self.model, (self.z0 + dz) * self.free.scale()).sim_config(control)


@dataclass
class _Scan:
    """What ``_would_be`` needs besides the sizes: the log's judge rows and their residuals under
    the final model, its noise floor, and the share of the error a fit on one joint must remove."""

    problem: Problem
    model: Model
    rows: np.ndarray
    residual: np.ndarray   # (N, C)
    floor_mse: float
    one_joint_removes: float
    absorbed: _Absorbed | None  # what the final model's effects absorb (None: it holds none)
    t: Thresholds               # the selection's: what ``--auto`` would add


def limits(problem: Problem, model: Model, rows: np.ndarray, residual: np.ndarray, floor_mse: float,
           candidates: tuple[str, ...], one_joint: bool = False, floor_says_noise: bool = False,
           t: Thresholds = THRESHOLDS) -> list[Limit]:
    """The limit of every parameter with a realistic range of the ``candidates`` ``model`` does not
    hold, on judge ``rows`` whose residuals under ``model`` are ``residual`` (N, C). ``one_joint``:
    per-joint parameters are also scanned on one joint at a time (module docstring), where a fit
    must remove ``t.structured_share`` of the error if ``floor_says_noise``; ``t``: the selection's
    thresholds (``policy``)."""
    held = {e.name for e in model.effects}
    scan = _Scan(problem, model, rows, residual, floor_mse, t.structured_share if floor_says_noise else 0.0,
                 _Absorbed.by(problem, model, rows) if set(candidates) - held else None, t)
    out = []
    for name in candidates:
        if name in held:
            continue
        effect = get_effect(name)
        for p in effect.parameters:
            if p.realistic is not None:
                limit = _limit(scan, effect, p)
                if one_joint and p.per_joint and not limit.inert:
                    limit.one_joint, limit.by_joint = _least_shown_joint(scan, effect, p)
                out.append(limit)
    return out


def _limit(scan: _Scan, effect: Effect, p: Parameter, joint: int | None = None, grid=None) -> Limit:
    """The limit of ``p`` on every joint alike, or on ``joint`` alone; ``grid``: its scan at
    ``sizes`` where already simulated (removed, z, detected)."""
    nominal = p.nominal_for(scan.problem.control)
    values = sizes(p, scan.problem.control, scan.t)
    removed, z, detected = grid if grid is not None else _would_be(scan, effect, p, values, joint)
    value = None
    if detected.any():
        j = int(np.argmax(detected))
        lo, hi = (values[j - 1], values[j]) if j else (nominal, values[0])
        for _ in range(BISECTIONS if j else 0):  # halve the bracket in the log of the distance from nominal
            mid = nominal + np.sign(hi - nominal) * np.sqrt(abs(lo - nominal) * abs(hi - nominal))
            shown = _would_be(scan, effect, p, np.array([mid]), joint)[2][0]
            lo, hi = (lo, mid) if shown else (mid, hi)
        value = float(hi)
    return Limit(effect.name, p.name, p.unit, nominal, values, removed, z, detected, value, tuple(p.realistic),
                 joint=JOINT_NAMES[joint] if joint is not None else "")


def _least_shown_joint(scan: _Scan, effect: Effect, p: Parameter) -> tuple[Limit, np.ndarray]:
    """``p`` on each joint alone at the grid's sizes (one batch): the limit of the joint the log
    shows least (the latest first size shown, ties to the smallest share removed there) and each
    joint's smallest grid size shown (nan: none)."""
    values = sizes(p, scan.problem.control, scan.t)
    k, n = len(values), len(JOINT_NAMES)
    removed, z, detected = (x.reshape(n, k) for x in _would_be(scan, effect, p, np.tile(values, n),
                                                                np.repeat(np.arange(n), k)))
    first = np.where(detected.any(1), detected.argmax(1), k)  # k: not shown at any size
    at = np.minimum(first, k - 1)
    by_joint = np.where(first < k, values[at], np.nan)
    least = max(range(n), key=lambda i: (first[i], -removed[i, at[i]]))
    return _limit(scan, effect, p, least, (removed[least], z[least], detected[least])), by_joint


def _would_be(scan: _Scan, effect: Effect, p: Parameter, values: np.ndarray,
              joints: np.ndarray | int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At each of ``values`` of ``p`` (on every joint, or on ``joints``: one joint index per value,
    or one for all): the share of the would-be error r + s a perfect fit removes, its paired z and
    whether ``--auto`` would add it at one step (module docstring)."""
    control = scan.problem.control
    if joints is not None:
        joints = np.broadcast_to(joints, values.shape)
    configs = []
    for i, v in enumerate(values):
        vals = effect.nominal(control)
        if not p.per_joint:
            vals[p.name] = float(v)
        elif joints is None:
            vals[p.name] = np.full_like(vals[p.name], v)
        else:
            vals[p.name] = np.array(vals[p.name], dtype=float)
            vals[p.name][joints[i]] = v
        configs.append(scan.model.with_effect(effect, vals).sim_config(control))
    k, rows, residual = len(configs), scan.rows, scan.residual
    n = len(rows)
    with_effect = scan.problem.residual_of(configs, np.tile(rows, k), model_of_row=np.repeat(np.arange(k), n))
    # r + s, s = r - (r with the effect); blown up: error 10, as judged
    would_be = [np.where(np.isfinite(w), w, 10.0) for w in np.split(2.0 * np.tile(residual, (k, 1)) - with_effect, k)]
    least_removed = scan.one_joint_removes if joints is not None else 0.0
    judged = np.array([_judged(scan, w, least_removed) for w in would_be])
    if scan.absorbed is not None:
        groups = [np.arange(k)] if joints is None else [np.flatnonzero(joints == g) for g in np.unique(joints)]
        _absorb(scan, would_be, judged, groups, least_removed)
    return judged[:, 0], judged[:, 1], judged[:, 2].astype(bool)


def _absorb(scan: _Scan, would_be: list[np.ndarray], judged: np.ndarray, groups: list[np.ndarray],
            least_removed: float) -> None:
    """Judge again (in place) with the final model's effects moved to explain each signature
    (module docstring), where that can change the limit: absorbing only lowers the would-be
    error, so only sizes shown without it can turn, and a larger size of the same parameter on
    the same joints is taken to stay shown once one is. So per group of sizes (ascending), from
    the first shown without absorbing up to the first shown with it, one batch per round."""
    a, control, rows = scan.absorbed, scan.problem.control, scan.rows
    pending = [g[judged[g, 2].astype(bool)] for g in groups]
    while pending := [g for g in pending if len(g)]:
        heads = [int(g[0]) for g in pending]
        configs = [a.config(a.step(would_be[j] - scan.residual), control) for j in heads]
        m = len(heads)
        moved = scan.problem.residual_of(configs, np.tile(rows, m), model_of_row=np.repeat(np.arange(m), len(rows)))
        for j, r_moved in zip(heads, np.split(np.where(np.isfinite(moved), moved, 10.0), m)):
            other = r_moved + would_be[j] - scan.residual
            if np.mean(other ** 2) < np.mean(would_be[j] ** 2):
                judged[j] = _judged(scan, other, least_removed)
        pending = [g[1:] if not judged[g[0], 2] else g[:0] for g in pending]


def _judged(scan: _Scan, would_be: np.ndarray, least_removed: float) -> tuple[float, float, bool]:
    """The share of the would-be error (N, C) a perfect fit removes (it leaves the final model's
    residual), its paired z, and whether ``--auto`` would add it at one step."""
    step = judgement(would_be, scan.residual, t=scan.t)
    shown = step.significant and not too_little(step, None, scan.floor_mse, t=scan.t) and step.removed >= least_removed
    return step.removed, step.z, shown
