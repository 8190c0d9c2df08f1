"""The noise floor: the part of the one-step error that no function of the recorded state and
actions predicts.

A model error caused by a missing physical effect is a function of what the robot was doing
(state, actions, action history); measurement noise is not. Ridge regressions learn the
normalised one-step residual on the fit rows from a library of candidate terms (PySINDy
style):

- per joint, one regression shared by the 12 joints (so it sees 12 samples per row), each term
  with its own coefficient per joint type: the joint's angle, speed, |speed|, speed^2,
  sign-like tanh(speed / 0.2 rad/s), PD error, action change, the foot's contact and its
  products with the PD error and speed, and a constant per joint;
- for the trunk channels, one regression on the whole state, actions and action changes.

The terms are instrumented (two-stage least squares): the model starts each row from the
measured state, so row t's residual carries the sensor noise of the state at t, and terms of
that same state would learn to predict part of the noise (the floor came out too low on noisy
logs: a correct friction fit "explained" 75 % of the error above it). So each term at row t is
first predicted, by least squares on the fit rows, from the terms at rows t - 2 and t + 2 (which
share no noise with row t), and the residual is regressed on those predictions. Rows without
both neighbours in their episode are left out of the floor. Where joint velocities are derived
from the angles, rows t -+ 2 do share angle readings with row t (its start reads back to t - 2,
``Problem.starts``; a derived velocity at t + 2 reads t + 1); measured on four logs behind a
10 ms filter, under the true model, the floor is 0.985-0.994 of the error with the terms 2
rows away and 0.988-0.994 with them 5 away, so they stay at 2.

What they leave on held-out rows is the floor (per channel, never above the error itself).
A linear library cannot represent every effect, so the floor is an upper bound on sensor
noise; the pipeline lowers it to what the best fitted candidate achieves.
"""

from __future__ import annotations

import numpy as np

from acn.measurements.data import Measurements
from acn.diagnosis.fitting import IV_LAG as LAG  # rows t - LAG and t + LAG share no noise with row t
from acn.sim.state import JOINT_NAMES, NUM_JOINTS, SLICES, STATE_NAMES

_SKIP = ("base_pos_x", "base_pos_y", "base_yaw")  # where the robot is and faces carries no dynamics
RIDGE = 1e-3  # regularisation, relative to the mean feature variance


def window_action(d: Measurements, rows: np.ndarray, unit: int = 1) -> np.ndarray:
    """(N, 12) the mean action over the ``unit`` control steps of one diagnosis step from each row."""
    return d.targets[rows] if unit == 1 else d.targets[rows[:, None] + np.arange(unit)[None]].mean(1)


def joint_library(d: Measurements, rows: np.ndarray, unit: int = 1) -> np.ndarray:
    """(N, 12, F) candidate terms per joint (module docstring)."""
    s, a = d.state[rows], window_action(d, rows, unit)
    prev = d.previous_actions(rows, 1, targets=True)[:, 0]
    q, qd = s[:, SLICES["joint_pos"]], s[:, SLICES["joint_vel"]]
    contact = np.nan_to_num(np.repeat(s[:, SLICES["contact"]], 3, axis=1))
    err = a - q
    terms = np.stack([q, qd, np.abs(qd), qd * np.abs(qd), np.tanh(qd / 0.2), err, a - prev, contact,
                      contact * err, contact * qd], axis=2)                          # (N, 12, T)
    kind = np.tile(np.eye(3), (4, 1))                                                # joint -> type
    by_type = (terms[:, :, :, None] * kind[None, :, None, :]).reshape(len(rows), NUM_JOINTS, -1)
    bias = np.broadcast_to(np.eye(NUM_JOINTS), (len(rows), NUM_JOINTS, NUM_JOINTS))
    return np.nan_to_num(np.concatenate([by_type, bias], axis=2))


def body_library(d: Measurements, rows: np.ndarray, unit: int = 1) -> np.ndarray:
    """(N, F): [1, state without x, y, yaw, a_t, a_t - a_{t-1}] (a_t: over the diagnosis step)."""
    keep = [i for i, n in enumerate(STATE_NAMES) if n not in _SKIP]
    a = window_action(d, rows, unit)
    prev = d.previous_actions(rows, 1, targets=True)[:, 0]
    return np.nan_to_num(np.concatenate([np.ones((len(rows), 1)), d.state[rows][:, keep], a, a - prev], axis=1))


def _ridge_left(x_fit: np.ndarray, y_fit: np.ndarray, x_held: np.ndarray, y_held: np.ndarray) -> np.ndarray:
    """Squared held-out residual (N_held, outputs) after a ridge regression fitted on the fit rows."""
    mu, sd = x_fit.mean(0), x_fit.std(0)
    sd = np.where(sd > 1e-12, sd, 1.0)
    xf, xh = (x_fit - mu) / sd, (x_held - mu) / sd
    xf, xh = np.hstack([xf, np.ones((len(xf), 1))]), np.hstack([xh, np.ones((len(xh), 1))])
    gram = xf.T @ xf
    coef = np.linalg.solve(gram + RIDGE * len(xf) * np.eye(len(gram)), xf.T @ y_fit)
    return (xh @ coef - y_held) ** 2


def _instrumented(library, d: Measurements, fit_rows: np.ndarray, held_rows: np.ndarray, unit: int = 1):
    """The library at rows t, as predicted (least squares on the fit rows) from the library at
    rows t - LAG and t + LAG, for fit and held-out rows: two-stage least squares. The measured
    state at t carries the very sensor noise that row t's residual carries (the model starts
    from it); the rows around share none of it, so what the second stage predicts is dynamics,
    not noise."""
    def stacked(rows):
        x = library(d, rows, unit)
        z = np.concatenate([library(d, rows - LAG * unit, unit), library(d, rows + LAG * unit, unit)], axis=-1)
        return x.reshape(-1, x.shape[-1]), z.reshape(-1, z.shape[-1])

    (xf, zf), (_, zh) = stacked(fit_rows), stacked(held_rows)
    zf1, zh1 = np.hstack([zf, np.ones((len(zf), 1))]), np.hstack([zh, np.ones((len(zh), 1))])
    gram = zf1.T @ zf1
    coef = np.linalg.solve(gram + 1e-9 * np.trace(gram) / len(gram) * np.eye(len(gram)), zf1.T @ xf)
    return zf1 @ coef, zh1 @ coef


def noise_floor(d: Measurements, channel_names: list[str], fit_rows: np.ndarray, r_fit: np.ndarray,
                held_rows: np.ndarray, r_held: np.ndarray, unit: int = 1) -> np.ndarray:
    """(C,) held-out MSE per compared channel left after the regressions (module docstring); a
    residual spans ``unit`` control steps (the terms' actions are averaged over them, the
    instruments lie LAG such steps away)."""
    lag = LAG * unit
    f_ok = d.with_neighbours(fit_rows, lag) & d.with_neighbours(fit_rows, lag + unit - 1)
    h_ok = d.with_neighbours(held_rows, lag) & d.with_neighbours(held_rows, lag + unit - 1)
    use_iv = f_ok.sum() >= 50 and h_ok.sum() >= 10  # else (short episodes) the terms of row t's own state
    if use_iv:
        fit_rows, r_fit, held_rows, r_held = fit_rows[f_ok], r_fit[f_ok], held_rows[h_ok], r_held[h_ok]
    left = r_held ** 2
    per_joint = [[channel_names.index(c) for c in (f"{j}_pos", f"{j}_vel") if c in channel_names]
                 for j in JOINT_NAMES]

    def features(library):
        if use_iv:
            return _instrumented(library, d, fit_rows, held_rows, unit)
        xf, xh = library(d, fit_rows, unit), library(d, held_rows, unit)
        return xf.reshape(-1, xf.shape[-1]), xh.reshape(-1, xh.shape[-1])

    if all(per_joint) and len({len(c) for c in per_joint}) == 1:
        cols = np.array(per_joint)                                     # (12, outputs)
        xf, xh = features(joint_library)
        yf, yh = r_fit[:, cols], r_held[:, cols]                       # (N, 12, outputs)
        out = _ridge_left(xf, yf.reshape(-1, yf.shape[2]), xh, yh.reshape(-1, yh.shape[2]))
        left[:, cols] = out.reshape(yh.shape)
    joint_channels = {c for cols in per_joint for c in cols}
    body = [i for i in range(len(channel_names)) if i not in joint_channels]
    if body:
        xf, xh = features(body_library)
        left[:, body] = _ridge_left(xf, r_fit[:, body], xh, r_held[:, body])
    return np.minimum(left.mean(0), (r_held ** 2).mean(0))
