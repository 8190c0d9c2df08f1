"""Fit one effect's parameters to measurements: least squares on re-simulated one-step
predictions (``mujoco.minimize.least_squares``), standard errors from a sandwich over blocks of
consecutive rows (``_stderr``: one trajectory's rows share their errors).

A joint parameter is fitted at a GRANULARITY: one number shared by all joints (``shared``),
one per joint type (``type``: hip, thigh, calf), one per leg (``leg``) or one per joint
(``joint``). The optimiser works on parameters divided by their typical magnitude, so one
finite-difference step (10 % of it) suits every unit. Every point the optimiser asks for in one
iteration is re-simulated in one batch (one model per point).

Jacobians are forward differences, except in ``central=True`` fits (``central_jacobian``),
which the diagnosis uses to refine the final fit of an effect whose parameters move the
measured start state (``traits.EffectTraits.moves_start``: encoder offsets move the feet
against the ground; ``policy.refine_chain``). There the one-step residual is rough at small
scales: at a step of 0.015 rad, forward and backward slopes differed by more than their mean in
59 % of the rows of a noise-free offsets log, and a forward difference overstated the slope
(Jacobian norm 34.8 forward, 27.0 central), so Gauss-Newton steps fell short and the interval
half-widths too.
Measured on that log (12 offsets, one fit from nominal, 12 iterations): forward differences
left 32.6 % of the offsets' norm (172 evaluations; 11.9 % after 36 iterations), central ones
10.8 % within the same evaluations and 3.6 % within the budget given for them (2 n + 3
evaluations per iteration, 328 here). Not everywhere: with central differences in every fit,
the 12 offsets also fitted a few per cent of a torque-limit log's error (4-17 mrad, no offsets
hidden), and ``--auto`` added them (``benchmarks/diagnose_cases.py``), which is why
the effects are chosen with forward differences and only the chosen ones are refined.
The fit over several steps (``multistep_refit``) takes central differences too where effects
are refitted beside it: over five steps a payload and the PD gains lie along a curved valley
((robot + payload mass) / kp nearly constant), where 10 % forward steps mislead Gauss-Newton
and the fit stops ("insufficient reduction") at a point that fits worse than the truth.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from mujoco import minimize

from acn.diagnosis.granularity import GRANULARITIES, GROUP_LABELS, GROUP_OF_JOINT
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.diagnosis.traits import traits
from acn.sim.effects import Effect, Model, Parameter, Values
from acn.sim.resim import Resimulator

DIVERGED_RESIDUAL = 10.0  # normalised residual given to a prediction that blew up
FD_STEP = 0.1             # finite-difference step, as a fraction of a parameter's typical magnitude


def central_jacobian(residual, lower: np.ndarray, upper: np.ndarray, step: float = FD_STEP):
    """``jac(x, r)`` for ``mujoco.minimize.least_squares``: central differences of the batched
    ``residual`` (2 n points in one call), one-sided where a bound cuts the step."""
    lower, upper = lower.reshape(-1, 1), upper.reshape(-1, 1)

    def jac(x: np.ndarray, r: np.ndarray) -> np.ndarray:
        x = x.reshape(-1, 1)
        n = len(x)
        plus, minus = np.minimum(x + step * np.eye(n), upper), np.maximum(x - step * np.eye(n), lower)
        both = residual(np.concatenate([plus, minus], axis=1))
        return (both[:, :n] - both[:, n:]) / (plus - minus).diagonal()

    return jac


def _jacobian(residual, z: np.ndarray, r: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              central: bool) -> np.ndarray:
    """The residual's Jacobian at ``z`` (scaled units): central or forward differences."""
    if central:
        return central_jacobian(residual, lower, upper)(z, r)
    return minimize.jacobian_fd(residual, z.reshape(-1, 1), r.reshape(-1, 1), np.float64(FD_STEP), 0,
                                [lower.reshape(-1, 1), upper.reshape(-1, 1)])[0]


class SoftL1(minimize.Norm):
    """Pseudo-Huber norm sum delta^2 (sqrt(1 + (r / delta)^2) - 1): quadratic for small residuals,
    linear for large ones. A few rows whose contacts switch under a small parameter change jump
    by a lot; this keeps them from dominating the fit (the judgement stays on squared error)."""

    def __init__(self, delta: float) -> None:
        self.delta = float(delta)

    @classmethod
    def around(cls, r: np.ndarray) -> "SoftL1":
        """The norm 3 robust sigmas of the residual ``r`` wide (at least 1e-9)."""
        return cls(max(3.0 * 1.4826 * float(np.median(np.abs(r))), 1e-9))

    def weights(self, r: np.ndarray) -> np.ndarray:
        """psi(r) / r: how much each residual counts (1 for small ones, delta / |r| for large ones)."""
        return 1.0 / np.sqrt(1.0 + (r / self.delta) ** 2)

    def value(self, r: np.ndarray) -> np.float64:
        d = self.delta
        return np.float64(np.sum(d * d * (np.sqrt(1.0 + (r / d) ** 2) - 1.0)))

    def grad_hess(self, r: np.ndarray, proj: np.ndarray):
        w = self.weights(r)
        return proj.T @ (r * w), proj.T @ (proj * (w ** 3))


@dataclass
class FreeParameters:
    """The vector an optimiser moves, and how it maps onto an effect's values."""

    effect: Effect
    granularity: str
    base: Values  # values of the parameters before the fit (nominal, or the model's current ones)

    def _size(self, p: Parameter) -> int:
        return int(GROUP_OF_JOINT[self.granularity].max()) + 1 if p.per_joint else 1

    @property
    def names(self) -> list[str]:
        """``value`` for a shared parameter, ``value[thigh]``, ``value[FR]``, ``value[FR_hip]`` otherwise."""
        out = []
        for p in self.effect.parameters:
            n = self._size(p)
            out += [p.name] if n == 1 else [f"{p.name}[{g}]" for g in GROUP_LABELS[self.granularity]]
        return out

    def per_joint(self) -> np.ndarray:
        """Which free parameters belong to a joint parameter (bool per free parameter)."""
        return np.array([p.per_joint for p in self.effect.parameters for _ in range(self._size(p))], bool)

    def scale(self) -> np.ndarray:
        """Typical magnitude per free parameter (optimiser units)."""
        out = []
        for p in self.effect.parameters:
            typical = max(abs(p.realistic[1]) if p.realistic else 0.0, abs(p.nominal) * 0.1, 1e-3)
            if p.from_control:
                typical = max(typical, 5.0)
            out += [typical] * self._size(p)
        return np.array(out)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = [], []
        for p in self.effect.parameters:
            lo += [p.lower] * self._size(p)
            hi += [p.upper] * self._size(p)
        return np.array(lo), np.array(hi)

    def vector(self, values: Values) -> np.ndarray:
        """Group means of ``values`` as a free-parameter vector."""
        out = []
        group = GROUP_OF_JOINT[self.granularity]
        for p in self.effect.parameters:
            v = np.asarray(values[p.name], float)
            out += [float(v[group == g].mean()) for g in range(self._size(p))] if p.per_joint else [float(v)]
        return np.array(out)

    def values(self, x: np.ndarray) -> Values:
        out: Values = {}
        i = 0
        group = GROUP_OF_JOINT[self.granularity]
        for p in self.effect.parameters:
            n = self._size(p)
            out[p.name] = x[i:i + n][group] if p.per_joint else float(x[i])
            i += n
        return out


def granularity_of(effect: Effect, values: Values) -> str:
    """The coarsest granularity that represents ``values`` exactly."""
    for g in GRANULARITIES:
        free = FreeParameters(effect, g, values)
        if all(np.allclose(free.values(free.vector(values))[p.name], values[p.name]) for p in effect.parameters):
            return g
    return "joint"


MAX_REFIT = 6  # free parameters of earlier effects refitted with a new one (offsets per joint are not)


def refittable(model: Model) -> tuple[str, ...]:
    """Effects of ``model`` refitted whenever another is fitted, while they stay few parameters."""
    out, total = [], 0
    for t in model.effects:
        n = len(FreeParameters(t.effect, granularity_of(t.effect, t.values), t.values).names)
        if total + n <= MAX_REFIT:
            out.append(t.name)
            total += n
    return tuple(out)


@dataclass
class Together:
    """The new effect's free parameters, then those of effects already in the model that are
    refitted with it (a second effect shifts what the first one was fitted to absorb)."""

    parts: list[FreeParameters]

    @property
    def effect(self) -> Effect:
        return self.parts[0].effect

    @property
    def names(self) -> list[str]:
        return self.parts[0].names + [f"{p.effect.name}.{n}" for p in self.parts[1:] for n in p.names]

    def scale(self) -> np.ndarray:
        return np.concatenate([p.scale() for p in self.parts])

    def per_joint(self) -> np.ndarray:
        return np.concatenate([p.per_joint() for p in self.parts])

    def effect_of(self) -> np.ndarray:
        """The effect's name per free parameter."""
        return np.array([p.effect.name for p in self.parts for _ in p.names])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = zip(*(p.bounds() for p in self.parts))
        return np.concatenate(lo), np.concatenate(hi)

    def start(self, values: Values | None) -> np.ndarray:
        first = self.parts[0]
        return np.concatenate([first.vector(values or first.base), *(p.vector(p.base) for p in self.parts[1:])])

    def split(self, x: np.ndarray) -> list[Values]:
        out, i = [], 0
        for p in self.parts:
            n = len(p.names)
            out.append(p.values(x[i:i + n]))
            i += n
        return out

    def model(self, base: Model, x: np.ndarray) -> Model:
        for part, values in zip(self.parts, self.split(x)):
            base = base.with_effect(part.effect, values)
        return base


@dataclass
class EffectFit:
    """One fitted effect."""

    effect: Effect
    granularity: str
    values: Values
    names: list[str]
    x: np.ndarray            # fitted free parameters
    stderr: np.ndarray       # their standard errors (``_stderr``: blocks of rows)
    model: Model             # the base model with this effect added
    cost: float              # mean squared normalised residual on the fit rows
    evaluations: int
    nominal: Values          # the values at which the effect is absent (for these control settings)
    contradicted: str = ""   # why the measurements contradict the values without simulation (``EffectTraits.check``)


class _OutOfBudget(Exception):
    pass


class Objective:
    """z (n, k) -> stacked normalised residuals ``horizon`` diagnosis steps ahead (rows * C, k),
    z = free parameters / scale.

    All k points are re-simulated in one batch. It counts model evaluations, stops the
    optimiser past ``budget`` of them, and remembers the best point it saw under ``norm``.
    """

    def __init__(self, problem: Problem, base: Model, free: Together, rows: np.ndarray, budget: int,
                 horizon: int = 1) -> None:
        d = problem.data
        self.problem, self.base, self.free, self.rows, self.horizon = problem, base, free, rows, horizon
        self.scale = free.scale()
        self.actions = problem.actions(rows, horizon)  # (N, steps, 12): ``horizon`` diagnosis steps
        self.previous = d.previous_actions(rows, problem.history)
        self.budget, self.evaluations = budget, 0
        self.norm: minimize.Norm | None = None
        self.best_cost, self.best_z, self.best_r = np.inf, None, None

    def __call__(self, z: np.ndarray) -> np.ndarray:
        z = z.reshape(len(self.scale), -1)
        k = z.shape[1]
        if self.evaluations + k > self.budget:
            raise _OutOfBudget
        configs = [self.free.model(self.base, z[:, j] * self.scale).sim_config(self.problem.control)
                   for j in range(k)]
        n = len(self.rows)
        model = np.repeat(np.arange(k), n)
        with Resimulator(self.problem.backend, configs, threads=self.problem.threads) as sim:
            starts = self.problem.starts(sim, np.tile(self.rows, k), configs, model)
            pred = sim.run(starts, np.tile(self.actions, (k, 1, 1)), np.tile(self.previous, (k, 1, 1)), model=model)
        self.evaluations += k
        r = self.problem.residual(pred.state[:, -1], np.tile(self.rows, k), self.horizon)
        r = np.where(np.isfinite(r), r, DIVERGED_RESIDUAL).reshape(k, -1).T / np.sqrt(n)
        if self.norm is not None:
            for j in range(k):
                cost = float(self.norm.value(r[:, j]))
                if cost < self.best_cost:
                    self.best_cost, self.best_z, self.best_r = cost, z[:, j].copy(), r[:, j].copy()
        return r.astype(np.float64)


def _together(problem: Problem, base: Model, effect: Effect, granularity: str, refit: tuple[str, ...]) -> Together:
    current = next((t.values for t in base.effects if t.name == effect.name), None)
    parts = [FreeParameters(effect, granularity, current or effect.nominal(problem.control))]
    for t in base.effects:
        if t.name in refit and t.name != effect.name:
            parts.append(FreeParameters(t.effect, granularity_of(t.effect, t.values), t.values))
    return Together(parts)


def fit_effect(problem: Problem, base: Model, effect: Effect, granularity: str, rows: np.ndarray,
               start: Values | None = None, max_iter: int = 12, refit: tuple[str, ...] = (),
               central: bool = False, horizon: int = 1, scan: bool = True) -> EffectFit:
    """Robust least-squares fit of ``effect`` added to ``base`` on ``rows`` (module docstring).

    A coarse scan picks the start; ``mujoco.minimize.least_squares`` (pseudo-Huber norm) refines
    it within ``max_iter`` iterations and an evaluation budget (n + 3 per iteration: the Jacobian's
    n points and the trial steps; 2 n + 3 with ``central`` differences, module docstring); the
    best point seen is kept.
    ``refit``: names of effects in ``base`` whose parameters are fitted again together with it.
    ``horizon``: diagnosis steps predicted from each row (``rows`` must start that many;
    ``multistep_refit``). ``scan``: False starts the optimiser at ``start`` itself (a fit on fewer
    rows has found the basin already: ``policy.rank``).
    """
    free = _together(problem, base, effect, granularity, refit)
    guess = traits(effect.name).guess
    if start is None and guess is not None and all(t.name != effect.name for t in base.effects):
        start = _clipped(effect, guess(problem.data.state[problem.fit_rows]))
    lo, hi = free.bounds()
    n_free = len(free.names)
    objective = Objective(problem, base, free, rows, budget=8 + max_iter * ((2 if central else 1) * n_free + 3),
                          horizon=horizon)
    scale = objective.scale
    z0 = np.clip(free.start(start) / scale, lo / scale, hi / scale)
    if scan:
        z, r, sensitive = _scan_start(objective, z0, free, lo / scale, hi / scale)
    else:
        z, r, sensitive = z0, objective(z0.reshape(-1, 1))[:, 0], True
    # Stages: the pseudo-Huber width follows the residual down (3 robust sigmas of the current
    # residual), so rows that jump stay outliers as the fit closes in.
    stages = 1 if max_iter <= 3 else 3
    for stage in range(stages if sensitive else 0):
        objective.norm = SoftL1.around(r)
        objective.best_cost, objective.best_z, objective.best_r = float(objective.norm.value(r)), z, r
        try:
            minimize.least_squares(z, objective, bounds=[lo / scale, hi / scale], norm=objective.norm, eps=FD_STEP,
                                   jacobian=central_jacobian(objective, lo / scale, hi / scale) if central else None,
                                   max_iter=-(-max_iter // stages), verbose=0, xtol=1e-3, gtol=1e-10,
                                   mu_factor=10.0 ** 0.5)
        except _OutOfBudget:
            break
        finally:
            z, r = objective.best_z, objective.best_r
    objective.budget = np.inf  # the Jacobian for the intervals is always computed
    jac = _jacobian(objective, z, r, lo / scale, hi / scale, central)
    stderr = _stderr(r, jac, len(rows)) * scale
    x = z * scale
    values = free.split(x)[0]
    return EffectFit(effect, granularity, values, free.names, x, stderr, free.model(base, x),
                     cost=float(r @ r), evaluations=objective.evaluations, nominal=effect.nominal(problem.control),
                     contradicted=_contradiction(problem, effect, values))


def _contradiction(problem: Problem, effect: Effect, values: Values) -> str:
    """Why the measured fit rows contradict ``values`` without simulation (``traits.EffectTraits.check``;
    "" if not)."""
    check = traits(effect.name).check
    return check(problem.data.state[problem.fit_rows], values) if check else ""


def _clipped(effect: Effect, values: Values | None) -> Values | None:
    """A first guess kept inside the parameters' bounds."""
    if values is None:
        return None
    return {p.name: float(np.clip(values[p.name], p.lower, p.upper)) for p in effect.parameters}


def _scan_start(residual, z0: np.ndarray, free: Together, lo: np.ndarray, hi: np.ndarray):
    """A coarse scan along the realistic direction (one batch) so the optimiser starts near the basin.

    Parameters without a one-sided realistic range (signed ones) stay where they are. Returns the
    best point, its residual, and whether the residual moved at all (an effect the data carry no
    information on, such as a torque limit that is never reached, needs no refinement).
    """
    first = free.parts[0]
    target: list[float | None] = []
    for p in first.effect.parameters:
        target += [p.realistic_middle] * first._size(p)
    target += [None] * (len(z0) - len(target))  # effects refitted along stay where they are
    scale = free.scale()
    direction = np.array([(t / s if t is not None else z) for t, s, z in zip(target, scale, z0)]) - z0
    if np.abs(direction).max() < 1e-3:  # already there (a start from an earlier fit): refine from it
        return z0, residual(z0.reshape(-1, 1))[:, 0], True
    steps = np.array([0.0, 0.25, 0.5, 1.0, 1.6, 2.5])
    points = np.clip(z0[:, None] + direction[:, None] * steps[None], lo[:, None], hi[:, None])
    r = residual(points)
    best = int(np.argmin(np.sum(np.abs(r), axis=0)))
    moved = np.abs(r - r[:, :1]).max() > 1e-9 * max(1.0, float(np.abs(r).max()))
    return points[:, best], r[:, best], bool(moved)


SANDWICH_BLOCK = 10  # consecutive rows per block of the sandwich covariance (their residuals are correlated)


def sandwich(a: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """Covariance a^-1 B a^-T of an estimate solving sum_t scores_t(theta) = 0 with slope ``a`` (k, k),
    B summed over blocks of ``SANDWICH_BLOCK`` consecutive rows of ``scores`` (rows, k): rows of one
    trajectory share their errors over several steps, which a sum of per-row products ignores
    (a cluster-robust sandwich, the blocks as clusters). inf where ``a`` is singular."""
    k = a.shape[0]
    blocks = scores[: len(scores) // SANDWICH_BLOCK * SANDWICH_BLOCK].reshape(-1, SANDWICH_BLOCK, k).sum(1)
    if len(blocks) <= k or not np.all(np.isfinite(a)) or np.linalg.cond(a) > 1e15:
        return np.full((k, k), np.inf)
    a_inv = np.linalg.inv(a)
    b = blocks.T @ blocks * (len(scores) / (len(blocks) * SANDWICH_BLOCK)) * (len(blocks) / (len(blocks) - k))
    return a_inv @ b @ a_inv.T


def _stderr(r: np.ndarray, jac: np.ndarray, rows: int) -> np.ndarray:
    """Standard errors of a pseudo-Huber least-squares fit from its residual ``r`` (``rows`` x channels,
    row-major) and Jacobian at the optimum: the M-estimator's ``sandwich`` over blocks of rows, slope
    J' diag(psi'(r)) J, scores J' psi(r) per row (psi(r) = r / sqrt(1 + (r / delta)^2), the width
    delta the fit's: 3 robust sigmas). ``mujoco.sysid.calculate_intervals`` treats every residual
    as independent; one trajectory's rows are not: these came out 1.0-3.2x its on three logs' final
    fits and 1.4-5.6x on the hidden log's ranking of ``make results`` (docs/diagnosis.md). Both
    are the local slope's: neither sees a cost that is rough along a valley (two parameters trading
    off), nor a bias (a fitted value several of them from the truth is no rarity). inf for a
    parameter the residual does not depend on."""
    out = np.full(jac.shape[1], np.inf)
    moving = np.abs(jac).max(axis=0) > 0
    if moving.any():
        j, norm = jac[:, moving], SoftL1.around(r)
        _, slope = norm.grad_hess(r.reshape(-1, 1), j)  # J' diag(psi'(r)) J, as the fit's Gauss-Newton steps
        scores = (j * (norm.weights(r) * r)[:, None]).reshape(rows, -1, j.shape[1]).sum(1)
        out[moving] = np.sqrt(np.clip(np.diag(sandwich(slope, scores)), 0.0, None))
    return out


IV_LAG = 2         # diagnosis steps between a row and its instrument rows (noise correlated over fewer)
IV_MAX_COST = 1.05  # the instrumental fit may cost at most this much more than least squares (pseudo-Huber)


def _costs_too_much(before: np.ndarray, after: np.ndarray) -> bool:
    """Whether a refit's residuals ``after`` cost more than ``IV_MAX_COST`` x the fit's ``before``,
    under the pseudo-Huber norm 3 robust sigmas of ``before`` wide: removing a noise bias costs a
    few per cent of fit, more is an estimate gone astray (``instrumental_refit``, ``multistep_refit``)."""
    soft = SoftL1.around(before)
    return soft.value(after) > IV_MAX_COST * soft.value(before)


def _instrumented(problem: Problem, free: Together) -> np.ndarray:
    """Which of ``free``'s parameters the instrumental refit solves for: all of them where the
    fitted effect has joint parameters, else the joint parameters of the effects refitted beside it.
    Not the armature (``EffectTraits.least_squares_under_step``) where rows start from the model's
    step (``Problem.velocities_from_step``: the joint velocities were derived): that step reads the angles at t - 2 to t, which the instruments'
    rows t -+ IV_LAG read too, and the instruments moved armatures that least squares fitted within
    8 % (0.0199 for 0.02, 0.0194 for 0.0179) 20-31 % high (0.0240, 0.0234), 3.6 of their standard
    errors. Damping and friction keep their instruments: least squares put them 7 % and 17 % high.
    An armature fitted there counts as an effect without joint parameters: the instruments solve
    only the joint parameters beside it (they moved a lag beside it 4.7 -> 3.8 ms for 4.85)."""
    joint = free.per_joint()
    kept = np.array([traits(n).least_squares_under_step for n in free.effect_of()], dtype=bool) \
        if problem.velocities_from_step else np.zeros_like(joint)
    own = any(p.per_joint for p in free.effect.parameters) and not kept[0]
    return (np.ones_like(joint) if own else joint) & ~kept


def instrumental_refit(problem: Problem, base: Model, fit: EffectFit, rows: np.ndarray,
                       refit: tuple[str, ...] = (), iterations: int = 3, central: bool = False) -> EffectFit:
    """Correct the joint parameters of a least-squares fit for noise in the measured start states.

    The model starts from the MEASURED s_t; its noise enters the prediction damped by the very
    parameters being fitted, so least squares prefers parameters that damp noise (errors in
    variables: with sensor noise, damping and friction come out 15-25 % high, encoder offsets
    35 % off). Instrumental variables remove that bias: the estimating equation
    sum_t z_t W r_t(theta) = 0 takes as instrument z_t the mean sensitivity dr/dtheta at rows
    t - IV_LAG and t + IV_LAG, which follows the dynamics at t but shares no sensor noise with
    row t's start or next state. Chord steps (the slope fixed at the least-squares point, whose
    pseudo-Huber weights are kept) solve it; the least-squares fit is kept when the equation is
    ill-conditioned, the solution leaves the bounds or fits the rows much worse (IV_MAX_COST;
    measured: corrections of a noise bias change the cost by -9 % to +1 %, twelve encoder
    offsets gone astray by +22 %). Without noise both estimates agree
    (damping 0.5005 vs 0.5003 for 0.5); with noise the instrumental one is less precise but not
    biased, except through what is nonlinear in the noise (friction's sign of a noisy speed:
    0.375 -> 0.347 for 0.3 on one log, 0.38 -> 0.30 on another). Not for the trunk's payload:
    the instruments fail there (contacts switch between t - 2 and t + 2; measured 1.96 -> 1.53 kg
    for 2; ``multistep_refit`` corrects it instead).

    Which parameters it solves for (``_instrumented``): all of them where the fitted effect has
    joint parameters; where it has none (a delay, a lag, the floor), the joint parameters of the
    effects refitted beside it, the rest staying at their least-squares values. A joint effect's
    noise bias stays when another effect is fitted on top of it: on a 200 Hz torque log with floor
    friction 0.586 and damping 0.388, damping added first came out 0.796, and the floor's
    least-squares fit on top of it left it at 0.796 (one step is flat along it); solving the
    damping by instruments there gave 0.387 (floor 0.580 by least squares). Solving the delay's
    or lag's own parameter too moved it astray (lag 12.0 -> 8.3 ms for 12.2 beside PD gains,
    4.6 -> 4.1 ms for 4.8 beside armature; the floor 0.580 -> 0.644).
    """
    free = _together(problem, base, fit.effect, fit.granularity, refit)
    solved = _instrumented(problem, free)
    if traits(fit.effect.name).fit_over_steps or not solved.any():
        return fit
    step = IV_LAG * problem.unit  # control steps: the instruments' windows share no measured state with row t's
    rows = rows[problem.data.with_neighbours(rows, step) & problem.data.with_neighbours(rows, step + problem.unit - 1)]
    lag = np.concatenate([rows - step, rows + step])
    if len(rows) < 10 * len(fit.x):
        return fit
    lo, hi = free.bounds()
    objective = Objective(problem, base, free, np.concatenate([rows, lag]), budget=np.inf)
    scale = objective.scale
    z = fit.x / scale
    half = len(rows) * len(problem.channels)
    r = objective(z.reshape(-1, 1))[:, 0]
    r0 = r[:half].copy()

    def moved(zs: np.ndarray) -> np.ndarray:  # the residual as a function of the solved parameters alone
        points = np.repeat(z.reshape(-1, 1), zs.shape[1], axis=1)
        points[solved] = zs
        return objective(points)

    jac = _jacobian(moved, z[solved], r, (lo / scale)[solved], (hi / scale)[solved], central)
    j_now, instrument = jac[:half], 0.5 * (jac[half:2 * half] + jac[2 * half:])  # J at t +- IV_LAG, averaged
    w = SoftL1.around(r[:half]).weights(r[:half])  # the least-squares fit's robust weights, kept fixed
    a = instrument.T @ (w[:, None] * j_now)
    if not np.all(np.isfinite(a)) or np.linalg.cond(a) > 1e8:
        return fit
    for i in range(iterations):  # chord steps: the slope stays the one at the least-squares fit
        if i:
            r = objective(z.reshape(-1, 1))[:, 0]
        step = np.zeros_like(z)
        step[solved] = -np.linalg.solve(a, instrument.T @ (w * r[:half]))
        z_new = z + np.clip(step, -0.5, 0.5)  # at most half a typical magnitude per step
        if np.any(z_new < lo / scale) or np.any(z_new > hi / scale):
            return fit
        z = z_new
    r = objective(z.reshape(-1, 1))[:, 0][:half].reshape(len(rows), -1)
    if _costs_too_much(r0, r.ravel()):
        return fit  # removing a noise bias costs a few per cent of fit; more is an equation gone astray
    k = int(solved.sum())
    scores = (instrument.reshape(len(rows), -1, k) * (w.reshape(len(rows), -1) * r)[:, :, None]).sum(1)
    cov = sandwich(a, scores)  # the instrumental estimate's uncertainty
    x = z * scale
    values = free.split(x)[0]
    stderr = fit.stderr.copy()
    stderr[solved] = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * scale[solved]  # the instrumental estimate's own
    return EffectFit(fit.effect, fit.granularity, values, fit.names, x, stderr, free.model(base, x),
                     cost=fit.cost, evaluations=fit.evaluations + objective.evaluations, nominal=fit.nominal,
                     contradicted=_contradiction(problem, fit.effect, values))


def finer_gains(problem: Problem, fit: EffectFit, rows: np.ndarray, granularities: Sequence[str]) -> dict[str, float]:
    """For each of ``granularities`` (finer than ``fit``'s), the share of the squared residual on
    ``rows`` that one Gauss-Newton step from ``fit``'s values at that granularity would remove
    (plain least squares, inside the bounds): a screen of the finer fits, from one forward-difference
    Jacobian of ``fit``'s effect per joint (one re-simulation of ``rows`` per free parameter), whose
    columns summed over each group of joints are the Jacobian at every coarser granularity.

    A finer fit costs an optimisation at every granularity (12 + 3 re-simulations per iteration per
    joint); the screen costs one Jacobian for all of them. Linear from the coarser values and
    in-sample, it overstates what a fit removes on held-out rows where the data hold nothing finer,
    and understates it little where they do (a worn joint: the step moves one value far)."""
    free = _together(problem, fit.model, fit.effect, "joint", refit=())
    objective = Objective(problem, fit.model, free, rows, budget=np.inf)
    lo, hi = (b / objective.scale for b in free.bounds())
    z = np.clip(free.start(None) / objective.scale, lo, hi)
    r = objective(z.reshape(-1, 1))[:, 0]
    jac = _jacobian(objective, z, r, lo, hi, central=False)
    total = float(r @ r)
    out = {}
    for g in granularities:
        group = GROUP_OF_JOINT[g]
        a = _block_diagonal([np.eye(group.max() + 1)[group] if p.per_joint else np.ones((1, 1))
                             for p in fit.effect.parameters])  # per-joint values <- one value per group of g
        step, *_ = np.linalg.lstsq(jac @ a, -r, rcond=None)
        moved = np.clip(z + a @ step, lo, hi) - z
        left = r + jac @ moved
        out[g] = 1.0 - float(left @ left) / total if total > 0 else 0.0
    return out


def _block_diagonal(blocks: list[np.ndarray]) -> np.ndarray:
    out = np.zeros((sum(b.shape[0] for b in blocks), sum(b.shape[1] for b in blocks)))
    i = j = 0
    for b in blocks:
        out[i:i + b.shape[0], j:j + b.shape[1]] = b
        i, j = i + b.shape[0], j + b.shape[1]
    return out


MULTISTEP_ROWS = 600  # start rows of the multi-step refit (each predicted ``multistep_horizon`` steps)
MULTISTEP_ITER = 18   # its iterations: mass and centre of mass converge slowly together (measured: 6 left the
# payload of a pace log 11-18 % light, 18 within 5 %, 30 no closer)


def multistep_refit(problem: Problem, fit: EffectFit, rows: np.ndarray, refit: tuple[str, ...] = ()) -> EffectFit:
    """``fit`` (of ``fit.effect`` with the effects named in ``refit``, as ``fit_effect`` made it)
    refined from its values on predictions ``multistep_horizon`` diagnosis steps ahead.

    The one-step prediction starts from the MEASURED s_t, and its noise (velocities above all)
    moves the contact forces the model predicts: an errors-in-variables bias, measured as a
    payload fitted light. Over several steps the payload's signal grows while the start's noise
    enters once. Instruments (``instrumental_refit``) fail for the trunk: contacts switch between
    t - 2 and t + 2. Measured with forward differences (typical sensor noise, 4 x 10 s logs, the
    payload's mass): a pace log with 1.82 kg, 1.14 one-step -> 1.79 over 5 steps; 3.5 kg behind
    the trunk 3.37 -> 3.55. ``fit`` is kept where the refit makes the one-step prediction of
    ``rows`` worse by more than ``IV_MAX_COST`` (pseudo-Huber), as the instrumental refit is.

    Central differences (module docstring). Measured from 2.25 kg at the trunk's centre, on top
    of fitted PD gains (a pace log, 2.09 kg + kp x 0.618): forward differences stopped at 3.74 kg
    with kp x 0.687 (five-step cost 1.77, the truth's 1.58), central ones reached 2.18 kg with
    kp x 0.625 (1.574); on top of motor strength (sines, 0.67 kg + strength 0.910): 1.94 kg with
    0.990 (0.88, the truth's 0.83) against 0.82 kg with 0.922 (0.83). Only where effects are
    refitted beside it (``refit``): the valley lies between them. Alone (a pace log, 1.82 kg, 200
    starts) forward differences end at nearly the same cost (1.648 kg, 0.291; central 1.613 kg,
    0.286) in about 70 % of the time, which the test suite's 15 minutes need.
    """
    horizon = multistep_horizon(problem)
    if horizon is None:
        return fit
    starts = problem.sample(np.intersect1d(rows, problem.data.windows(problem.steps(horizon))), MULTISTEP_ROWS,
                            salt=horizon)
    if len(starts) < 10 * len(fit.x):
        return fit
    ahead = fit_effect(problem, fit.model, fit.effect, fit.granularity, starts, start=fit.values,
                       max_iter=MULTISTEP_ITER, refit=refit, horizon=horizon, central=bool(refit))
    one_step = Objective(problem, fit.model, _together(problem, fit.model, fit.effect, fit.granularity, refit), rows,
                         budget=np.inf)
    r = one_step(np.stack([fit.x, ahead.x], axis=1) / one_step.scale[:, None])
    if _costs_too_much(r[:, 0], r[:, 1]):
        return fit
    return replace(ahead, cost=fit.cost, evaluations=fit.evaluations + ahead.evaluations + one_step.evaluations)


def multistep_horizon(problem: Problem) -> int | None:
    """The shortest horizon above one diagnosis step that the problem compares (5 by default)."""
    return min((h for h in problem.scale if h > 1), default=None)


def rank_rows(problem: Problem, cfg: DiagnoseConfig) -> np.ndarray:
    """The fit rows every candidate is fitted on while ranking (the same sample for each)."""
    return problem.sample(problem.fit_rows, cfg.rank_rows, salt=3)


def screen_rows(problem: Problem, cfg: DiagnoseConfig) -> np.ndarray:
    """The fewer fit rows every candidate is first fitted on while ranking (``policy.rank``): a
    subsample of ``rank_rows``."""
    rows = rank_rows(problem, cfg)
    return rows if cfg.screen_rows >= len(rows) else problem.sample(rows, cfg.screen_rows, salt=6)


def final_rows(problem: Problem, cfg: DiagnoseConfig) -> tuple[np.ndarray, bool]:
    """The rows an added effect's final fit is made on: ``cfg.fit_rows`` of the fitting rows, or the
    ranking's rows where those are not fewer; and whether they are more than the ranking's."""
    rows, ranked = problem.sample(problem.fit_rows, cfg.fit_rows, salt=5), rank_rows(problem, cfg)
    return (rows, True) if len(rows) > len(ranked) else (ranked, False)


FINAL_ITER = 6  # iterations of a final fit on more rows, from the values of the fit it refines


def final_fit(problem: Problem, model: Model, fit: EffectFit, cfg: DiagnoseConfig, again: bool = False,
              central: bool = False) -> EffectFit:
    """``fit`` refitted on ``cfg.fit_rows`` rows from its values at its granularity (where those are
    more than the ranking's rows it was fitted on, or ``again``: on another base model), then the
    instrumental refit on the same rows; ``central``: both with central differences."""
    rows, more = final_rows(problem, cfg)
    if again or more:
        fit = fit_effect(problem, model, fit.effect, fit.granularity, rows, start=fit.values, max_iter=FINAL_ITER,
                         refit=refittable(model), central=central)
    return instrumental_refit(problem, model, fit, rows, refit=refittable(model), central=central)
