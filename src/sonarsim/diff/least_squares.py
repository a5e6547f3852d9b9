"""Least squares for the inverse tools: the free parameters' names and units, and
Levenberg-Marquardt with the held search refreshed at every point it evaluates (used by
:mod:`sonarsim.diff.inverse` and :mod:`sonarsim.diff.bands`)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

#: Free pose parameters by their short names and what they are in the parameter dict.
POSE_KEYS = {"x": ("sonar.position_m", 0), "y": ("sonar.position_m", 1), "z": ("sonar.position_m", 2),
             "roll": ("sonar.rpy_deg", 0), "pitch": ("sonar.rpy_deg", 1), "yaw": ("sonar.rpy_deg", 2)}
#: The optimiser's unit of each kind of parameter: 5 cm, 2.5 degrees, 10 dB, ... (comparable
#: steps; a key not listed: its value's size). The sensor's levels start tens of dB off.
UNITS = {"sonar.position_m": 0.05, "sonar.rpy_deg": 2.5, "sensor.gain_db": 10.0, "sensor.source_level_db": 10.0,
         "sensor.noise_db": 10.0, "sensor.noise_after_tvg_db": 10.0, "sensor.tvg_spreading": 5.0,
         "sensor.elevation_width_deg": 1.0, "sensor.azimuth_width_deg": 0.05, "sensor.gamma": 0.03}


def levenberg_marquardt(renderer, to_params, residuals, jacobian, u: np.ndarray, iterations: int,
                        tolerance: float = 1e-4, max_step: float = 1.0, ftol: float = 0.0,
                        held: np.ndarray | None = None) -> tuple[np.ndarray, float, int]:
    """Minimise ``|residuals(u)|^2`` from ``u`` (Levenberg-Marquardt, Marquardt's scaling), the
    search refreshed at every point evaluated: each step's loss is the loss of the frame the
    compiled engine would form there. Returns ``(u, loss, iterations)``."""
    renderer.refresh(to_params(jnp.asarray(u)))
    r = np.asarray(residuals(jnp.asarray(u)), float)
    loss = float(r @ r)
    lam = 1e-3
    it = 0
    slow = 0
    for it in range(1, iterations + 1):
        jac = np.array(jacobian(jnp.asarray(u)), float)
        if held is not None and held.any():
            jac[:, held] = 0.0
        jtj = jac.T @ jac
        g = jac.T @ r
        scale = np.maximum(np.diag(jtj), 1e-12 * max(float(np.max(np.diag(jtj))), 1e-300))
        improved = False
        while lam < 1e8:
            step = -np.linalg.solve(jtj + lam * np.diag(scale), g)
            # A trust region of one unit (5 cm, 2.5 degrees, 10 dB, ...) per step: the blurred
            # images are matched locally (a longer step may jump into another echo's basin).
            step = step * min(1.0, max_step / max(float(np.max(np.abs(step))), 1e-300))
            trial = u + step
            renderer.refresh(to_params(jnp.asarray(trial)))
            r_new = np.asarray(residuals(jnp.asarray(trial)), float)
            new = float(r_new @ r_new)
            if np.isfinite(new) and new < loss:
                gain = (loss - new) / loss if loss > 0 else 0.0
                u, r, loss, improved = trial, r_new, new, True
                lam = max(lam / 3.0, 1e-7)
                break
            lam *= 4.0
        if not improved:
            renderer.refresh(to_params(jnp.asarray(u)))  # back to the best point's search
            break
        slow = slow + 1 if gain < ftol and it > 3 else 0
        if float(np.max(np.abs(step))) < tolerance or slow >= 2:
            break
    return u, loss, it
