"""The study's answer: five routes to the robot in the paper's Table 1 layout, the share of the
gap each closes, and a one-sentence verdict.

Every route is a policy evaluated by ``acn-ppo --eval`` from the same held-out starts on the robot
(with or without a corrector) and in the model it was trained in, so every comparison is paired
per episode. The return is the policy's training reward (``training_returns``: the paper's four
terms with PPO's weights and the alive bonus), the objective every policy here was trained for;
the paper's reward rewards an early fall (a shorter sum of negative rewards), so it cannot rank
policies that fall. It is kept beside (``paper_on_robot``).

- transfer gap: return on the robot - return in the training model, per episode;
- share closed: (R_route - R_pi_sim) / (R_pi_robot - R_pi_sim) on the robot, per-episode
  differences averaged first (a ratio of means; its standard error by the delta method).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

ROBOT_RUNS = ("robot", "robot_corrected")


@dataclass(frozen=True)
class Route:
    """One way to the robot: which policy (its evaluation file), which run of it."""

    key: str        # the policy's name in the table
    policy: str     # the evaluation it comes from: "sim", "model" or "robot"
    run: str        # "robot" or "robot_corrected" (the corrector applied on the robot)
    advice: str     # what choosing it means

    @property
    def corrected(self) -> bool:
        return self.run == "robot_corrected"


ROUTES = (
    Route("pi_sim", "sim", "robot", "deploy the policy trained in the simulator as it is"),
    Route("pi_sim + F", "sim", "robot_corrected", "apply the corrector to the policy trained in the simulator"),
    Route("pi_M", "model", "robot", "train in the model the diagnosis identified"),
    Route("pi_M + F_M", "model", "robot_corrected", "train in the identified model and apply its corrector"),
    Route("pi_robot", "robot", "robot", "train on the robot itself"),
)
BASE, BOUND = "pi_sim", "pi_robot"


@dataclass(frozen=True)
class Estimate:
    """A mean with its standard error over n episodes."""

    mean: float
    se: float
    n: int

    @classmethod
    def of(cls, values) -> "Estimate":
        v = np.asarray(values, dtype=float)
        se = float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) > 1 else float("nan")
        return cls(float(v.mean()), se, len(v))

    def text(self, digits: int = 1, scale: float = 1.0, unit: str = "") -> str:
        se = "" if math.isnan(self.se) else f" ± {scale * self.se:.{digits}f}"
        return f"{scale * self.mean:.{digits}f}{se}{unit}"

    def clear_of_zero(self) -> bool:
        """More than two standard errors from zero."""
        return not math.isnan(self.se) and abs(self.mean) > 2 * self.se


def share_closed(route: np.ndarray, base: np.ndarray, bound: np.ndarray) -> Estimate:
    """(mean(route - base)) / (mean(bound - base)) with its delta-method standard error."""
    d, g = route - base, bound - base
    if g.mean() == 0:
        return Estimate(float("nan"), float("nan"), len(d))
    r = float(d.mean() / g.mean())
    se = float(np.std(d - r * g, ddof=1) / math.sqrt(len(d)) / abs(g.mean())) if len(d) > 1 else float("nan")
    return Estimate(r, se, len(d))


@dataclass
class RouteRow:
    """One line of the table."""

    route: str
    on_robot: Estimate
    in_training_model: Estimate
    transfer_gap: Estimate
    forward_speed: Estimate  # m/s, on the robot
    falls: int               # on the robot: fell or diverged
    episodes: int
    paper_on_robot: Estimate  # the paper's reward on the robot
    share_closed: Estimate | None = None  # of the pi_sim -> pi_robot gap on the robot
    # what each term of the training reward adds to the return on the robot (mean over episodes):
    # which term a route gains or loses in
    terms_on_robot: dict[str, float] | None = None


@dataclass
class TransferTable:
    rows: list[RouteRow]
    gap: Estimate     # pi_robot - pi_sim on the robot: the gap every route is measured against
    verdict: str

    @classmethod
    def from_evaluations(cls, evaluations: dict[str, dict]) -> "TransferTable":
        """``evaluations``: ``acn-ppo --eval`` results by policy ("sim", "model", "robot")."""
        returns = {r.key: np.asarray(evaluations[r.policy]["training_returns"][r.run], dtype=float)
                   for r in ROUTES if r.run in evaluations[r.policy]["training_returns"]}
        n = {len(v) for v in returns.values()}
        if len(n) != 1:
            raise ValueError(f"the evaluations have different numbers of episodes: {sorted(n)}")
        rows = []
        for r in ROUTES:
            if r.key not in returns:
                continue
            ev = evaluations[r.policy]
            own = np.asarray(ev["training_returns"]["sim"], dtype=float)
            ends = ev["episode_ends"][r.run]
            share = None
            if r.key not in (BASE, BOUND):
                share = share_closed(returns[r.key], returns[BASE], returns[BOUND])
            rows.append(RouteRow(
                route=r.key, on_robot=Estimate.of(returns[r.key]), in_training_model=Estimate.of(own),
                transfer_gap=Estimate.of(returns[r.key] - own),
                forward_speed=Estimate.of(ev["episode_forward_speed"][r.run]),
                falls=sum(e != "time_limit" for e in ends), episodes=len(ends),
                paper_on_robot=Estimate.of(ev["returns"][r.run]), share_closed=share,
                terms_on_robot=term_contributions(ev, r.run)))
        gap = Estimate.of(returns[BOUND] - returns[BASE])
        return cls(rows, gap, verdict(rows, gap))

    def row(self, route: str) -> RouteRow:
        return next(r for r in self.rows if r.route == route)

    # ----- output ---------------------------------------------------------------------------
    HEADER = ("policy", "return on the robot", "return in its training model", "transfer gap",
              "forward speed on the robot, m/s", "falls on the robot", "share of the gap closed")

    def cells(self) -> list[list[str]]:
        out = []
        for r in self.rows:
            share = "" if r.share_closed is None else r.share_closed.text(0, 100, " %")
            if r.route == BASE:
                share = "0 % (the start)"
            elif r.route == BOUND:
                share = "100 % (the bound)"
            out.append([r.route, r.on_robot.text(), r.in_training_model.text(), r.transfer_gap.text(),
                        r.forward_speed.text(2), f"{r.falls}/{r.episodes}", share])
        return out

    def markdown(self) -> str:
        lines = ["| " + " | ".join(self.HEADER) + " |", "|" + "---|" * len(self.HEADER)]
        lines += ["| " + " | ".join(c) + " |" for c in self.cells()]
        return "\n".join(lines)

    def text(self) -> str:
        rows = [list(self.HEADER)] + self.cells()
        widths = [max(len(r[i]) for r in rows) for i in range(len(self.HEADER))]
        return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)

    def by_term(self) -> list[str]:
        """For each route against pi_sim on the robot: where its return differs, term by term
        (largest first), which says why a route helps or does not."""
        base = self.row(BASE).terms_on_robot
        lines = []
        for r in self.rows:
            if r.route == BASE or r.terms_on_robot is None or base is None:
                continue
            diff = sorted(((k, r.terms_on_robot[k] - base[k]) for k in base), key=lambda kv: -abs(kv[1]))
            lines.append(f"{r.route} - pi_sim on the robot, by term: " + ", ".join(f"{k} {v:+.1f}" for k, v in diff))
        return lines

    def to_json(self) -> dict:
        return {"rows": [asdict(r) for r in self.rows], "gap": asdict(self.gap), "verdict": self.verdict,
                "by_term": self.by_term(),
                "return": "the training reward (PPO's weights of the paper's four terms and the alive bonus) per "
                          "episode; paper_on_robot: the paper's reward",
                "share_closed": "(R_route - R_pi_sim) / (R_pi_robot - R_pi_sim) on the robot, same starts"}


def term_contributions(evaluation: dict, run: str) -> dict[str, float] | None:
    """Mean over episodes of each weighted term of the training reward, and the alive bonus, on
    ``run`` (they add up to the return); None for an evaluation that does not record them."""
    if "episode_reward_terms" not in evaluation or "training_reward" not in evaluation:
        return None
    terms = np.asarray(evaluation["episode_reward_terms"][run], dtype=float)   # (episodes, 4), unweighted sums
    w = np.asarray(evaluation["training_reward"]["weights"], dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])
    out = dict(zip(evaluation["reward_term_names"], (terms * w).mean(axis=0).tolist()))
    alive = [steps - (end != "time_limit") for steps, end in zip(evaluation["episode_steps"][run],
                                                           evaluation["episode_ends"][run])]
    out["alive_bonus"] = float(evaluation["training_reward"]["alive_bonus"] * np.mean(alive))
    return out


def verdict(rows: list[RouteRow], gap: Estimate) -> str:
    """One sentence from the numbers: which route closes how much of the gap, and what to do."""
    by = {r.route: r for r in rows}
    routes = [r for r in rows if r.share_closed is not None]
    advice = {r.key: r.advice for r in ROUTES}
    if not gap.clear_of_zero():
        return (f"pi_sim walks on the robot about as well as pi_robot (return gap {gap.text()}, within two standard "
                "errors): on this robot there is no policy-level gap for a route to close.")
    if gap.mean < 0:
        return (f"pi_sim walks on the robot better than pi_robot (return gap {gap.text()}): training on the robot "
                "did not reach pi_sim's return at this size, so the shares are not meaningful.")
    parts = ", ".join(f"{r.route} {r.share_closed.text(0, 100, ' %')}" for r in routes)
    helped = [r for r in routes if r.share_closed.mean > 0 and r.share_closed.clear_of_zero()]
    if not helped:
        return (f"No route measurably closes the gap from pi_sim to pi_robot on the robot (return {gap.text()}; "
                f"share closed: {parts}).")
    top = max(helped, key=lambda r: r.share_closed.mean)
    # the routes within two standard errors of the best close as much; the simplest of them (the
    # first in ROUTES: no corrector before one) is the advice
    tied = [r for r in helped if top.share_closed.mean - r.share_closed.mean
            <= 2 * math.hypot(top.share_closed.se, r.share_closed.se)]
    best = tied[0]
    who = (f"{best.route} closes the most" if len(tied) == 1 else
           f"{' and '.join(r.route for r in tied)} close about as much, the most,")
    falls = f"; {best.route} falls {best.falls}/{best.episodes} times on the robot, pi_robot {by[BOUND].falls}/{by[BOUND].episodes}"
    return (f"{who} of the gap from pi_sim to pi_robot (return {gap.text()}; share closed: {parts}){falls}: "
            f"{advice[best.route]}.")
