"""Per-photo refinement of the photo's light from its own shading gradients (issue 26).

The network fits the photo's light L_a by ridge least squares of photo ~ rho_p * (T . L)
toward its light head (model.networks.physics.fit_light): the light is only as right as the
albedo prior rho_p. Within one piece of cloth or skin the albedo hardly changes, so
there the photo's log-gradients are the shading's:

    d log I_c  ~  d log (T . L_c)        (neighbouring pixels, per channel c)

This module refits L_c to those gradients, robustly (albedo edges are outliers: a
Cauchy loss), with a ridge toward the network's light, by Gauss-Newton iterations
with a backtracking step so that the objective never rises; it stops early when the
objective stops falling. Log-gradients do not see a channel's overall gain, so the
DC term (the light's colour and level) stays the network's. The albedo then follows from
the light by the model's own rule (`consistent_albedo`: relight.network.prt.photo_consistent_albedo,
the one function the exported graph runs too), so relighting stays photo x shading' / shading.

numpy only; cost ~ iterations x pixels x n^2 at working resolution (a few ms per
iteration at 128 px). Measured on held-out scenes in docs/TRADEOFFS.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.imaging.colour import srgb_decode, srgb_encode
from relight.network.prt import ALBEDO_MIN_MEAN, ALBEDO_RELIABLE, photo_consistent_albedo

__all__ = ["RefineReport", "albedo_from_input", "consistent_albedo", "refine", "refine_light"]

LOG_EPS = 1e-6        # added before the log: finite everywhere, negligible where pixels are fitted
DARK = 0.02           # pixels darker than this x the person's median are noise, not shading: not fitted
SHADING_FLOOR = 1e-3  # shading below this is "no light": its gradient is not fitted
SCALE = 0.05          # log-gradient residual beyond which a pair counts more and more as an albedo edge
RIDGE = 0.3           # pull toward the network's light, relative to the data's own scale
RELIABLE = ALBEDO_RELIABLE  # the photo-consistent albedo rule's constants (relight.network.prt: the one set)
MIN_MEAN = ALBEDO_MIN_MEAN
CLIPPED = 0.99        # sRGB-encoded value above which a pixel is saturated (not fitted)
SATURATED = float(srgb_decode(np.float64(CLIPPED)))  # the same in linear photo units
INTERIOR = 0.999      # alpha from which a pixel is inside the person (edges mix background)
MIN_PAIRS = 16        # fewer usable neighbour pairs: nothing to fit, the light is kept
TOLERANCE = 1e-4      # relative fall of the objective below which the iterations stop
BACKTRACKS = 6


@dataclass(frozen=True)
class RefineReport:
    """What one refinement did: the objective (robust log-gradient residual of the photo plus
    the ridge toward the network's light, summed over channels) before the first iteration
    and after each, how many iterations were taken and why it stopped."""

    residuals: tuple[float, ...]
    iterations: int
    stopped: str  # "converged", "iterations", "no pixels", "off"

    def as_dict(self) -> dict:
        return {"iterations": self.iterations, "stopped": self.stopped,
                "residual_before": self.residuals[0] if self.residuals else None,
                "residual_after": self.residuals[-1] if self.residuals else None}


def _pairs(inside: np.ndarray):
    """Flat indices (first, second) of horizontally and vertically neighbouring inside pixels."""
    h, w = inside.shape
    index = np.arange(h * w).reshape(h, w)
    right = inside[:, :-1] & inside[:, 1:]
    down = inside[:-1] & inside[1:]
    first = np.concatenate([index[:, :-1][right], index[:-1][down]])
    second = np.concatenate([index[:, 1:][right], index[1:][down]])
    return first, second


def _robust(r: np.ndarray) -> np.ndarray:
    """Cauchy loss of log-gradient residuals: quadratic below SCALE, then only logarithmic,
    so an albedo edge (a residual of ~1) hardly pulls the light."""
    return 0.5 * SCALE * SCALE * np.log1p((r / SCALE) ** 2)


def _channel_fit(t1, t2, g, prior, iterations, ridge):
    """Refit one channel's light [n] to its log-gradients g [m]: (light, objective values, steps, why)."""
    def residual(light):
        s1, s2 = t1 @ light, t2 @ light
        r = g - (np.log(np.maximum(s2, SHADING_FLOOR) + LOG_EPS) - np.log(np.maximum(s1, SHADING_FLOOR) + LOG_EPS))
        return r, s1, s2

    def jacobian(s1, s2):
        # d r / d light; a floored shading has no gradient
        return -(t2 * ((s2 > SHADING_FLOOR) / (np.maximum(s2, SHADING_FLOOR) + LOG_EPS))[:, None]
                 - t1 * ((s1 > SHADING_FLOOR) / (np.maximum(s1, SHADING_FLOOR) + LOG_EPS))[:, None])

    light = prior.copy()
    r, s1, s2 = residual(light)
    jac = jacobian(s1, s2)
    # the ridge's weight, fixed from the start's data scale: one objective throughout
    lam = ridge * max(float(np.einsum("ij,ij->", jac, jac)) / jac.shape[1], 1e-12)

    def objective(light, r):
        return float(_robust(r).sum() + 0.5 * lam * np.sum((light - prior) ** 2))

    values = [objective(light, r)]
    taken, stopped = 0, "iterations"
    for _ in range(iterations):
        w = 1.0 / (1.0 + (r / SCALE) ** 2)  # IRLS weights of the Cauchy loss
        normal = (jac * w[:, None]).T @ jac
        rhs = -(jac * w[:, None]).T @ r - lam * (light - prior)
        step = np.linalg.solve(normal + lam * np.eye(normal.shape[0]), rhs)
        for _ in range(BACKTRACKS):
            trial = light + step
            t_r, t_s1, t_s2 = residual(trial)
            value = objective(trial, t_r)
            if np.isfinite(value) and value < values[-1]:
                break
            step = step * 0.5
        else:
            stopped = "converged"  # no step lowers the objective
            break
        fall = values[-1] - value
        light, r, s1, s2 = trial, t_r, t_s1, t_s2
        jac = jacobian(s1, s2)
        values.append(value)
        taken += 1
        if fall <= TOLERANCE * values[-2]:
            stopped = "converged"
            break
    return light, values, taken, stopped


def refine_light(transport: np.ndarray, photo: np.ndarray, alpha: np.ndarray, light: np.ndarray,
                 iterations: int = 8, ridge: float = RIDGE) -> tuple[np.ndarray, RefineReport]:
    """The light [n, 3] refitted to the photo's shading gradients (module docstring).

    transport [h, w, n], photo (linear) [h, w, 3], alpha [h, w], light [n, 3] at working
    resolution. The person's mean shading per channel (alpha-weighted over the crop) stays what
    `light` gives: log-gradients cannot see the level and colour, and the albedo's level and
    colour rest on that mean (the level prior set it), so the refinement changes the light's
    pattern only. (Keeping the DC coefficient instead let the level drift with the pattern:
    -0.06 dB on Best's six runs, against +0.08 +- 0.04 now; docs/TRADEOFFS.md.)
    """
    if not (isinstance(iterations, (int, np.integer)) and iterations >= 0):
        raise ValueError(f"refine iterations must be an integer >= 0, got {iterations!r}")
    light = np.asarray(light, np.float64)
    if iterations == 0:
        return light.copy(), RefineReport((), 0, "off")
    encoded = srgb_encode(np.clip(photo, 0.0, 1.0).astype(np.float32))
    inside = (alpha >= INTERIOR) & (encoded.max(axis=-1) < CLIPPED)
    if np.any(inside):  # channels' own medians: a pixel dark in one channel is noise in it
        inside &= np.all(photo > DARK * np.median(photo[inside], axis=0), axis=-1)
    first, second = _pairs(inside)
    if first.size < MIN_PAIRS:
        return light.copy(), RefineReport((), 0, "no pixels")
    n = light.shape[0]
    t = transport.reshape(-1, transport.shape[-1])[:, :n].astype(np.float64)
    p = photo.reshape(-1, 3).astype(np.float64)
    t1, t2 = t[first], t[second]
    logp = np.log(np.maximum(p, 0.0) + LOG_EPS)
    grads = logp[second] - logp[first]
    weight = np.clip(alpha, 0.0, 1.0).reshape(-1).astype(np.float64)
    mean_t = weight @ t / max(float(weight.sum()), 1e-12)  # the person's mean transport: mean shading = mean_t . L
    out = light.copy()
    total_residuals, taken, stops = None, 0, []
    for c in range(3):
        fitted, residuals, k, stopped = _channel_fit(t1, t2, grads[:, c], light[:, c], int(iterations), ridge)
        before, after = float(mean_t @ light[:, c]), float(mean_t @ fitted)
        if before > 0 and after > 0:
            fitted = fitted * (before / after)  # the person's mean shading stays the network's
        else:
            fitted = light[:, c]
        out[:, c] = fitted
        # channels stop at different iterations: pad each with its last value
        residuals = residuals + [residuals[-1]] * (iterations + 1 - len(residuals))
        total_residuals = np.array(residuals) if total_residuals is None else total_residuals + residuals
        taken, stops = max(taken, k), stops + [stopped]
    stopped = "converged" if all(s == "converged" for s in stops) else "iterations"
    return out, RefineReport(tuple(float(v) for v in total_residuals[:taken + 1]), taken, stopped)


def consistent_albedo(d, transport: np.ndarray, light: np.ndarray, reliable: float = RELIABLE) -> np.ndarray:
    """The albedo [h, w, 3] the geometry-first network would derive for decomposition `d`
    with this transport [h, w, n] and light [n, 3] (`reliable`: the model's shading floor, a
    fraction of the mean; relight.command.clip passes the model's own): its photo-consistent rule (model.networks.geometry)
    on the working crop as the network input encodes it, weighted by the alpha head where that
    input is not saturated. The crop is taken unmasked: along the matte's soft edge the masked
    input fades toward the encoding's zero (sRGB 0.5 grey), which divided by the shading drew a
    pale ring around the person in the albedo layer and greyed the relit edge; unmasked, an
    edge pixel relights as the photo times shading' / shading. Inside the matte (alpha 1) the
    two are the same. Unmasked, the input's sRGB round trip is the photo clipped to [0, 1], so
    it is not computed (a sixth of the time)."""
    photo = np.clip(d.photo_working, 0.0, 1.0)
    alpha = d.network_alpha if d.network_alpha is not None else d.alpha
    weight = alpha * (photo.max(axis=-1) < SATURATED)
    return _albedo(photo, transport @ light, weight, reliable)


def _albedo(photo: np.ndarray, shading: np.ndarray, weight: np.ndarray, reliable: float = RELIABLE) -> np.ndarray:
    """relight.network.prt.photo_consistent_albedo of [h, w, 3] arrays with a weight [h, w], float32."""
    return photo_consistent_albedo(photo, shading, weight[..., None], reliable).astype(np.float32, copy=False)


def albedo_from_input(encoded: np.ndarray, alpha: np.ndarray, transport: np.ndarray,
                      light: np.ndarray) -> np.ndarray:
    """The geometry-first network's albedo [h, w, 3] from its own input (encoded [h, w, 3] in
    [-1, 1]), its alpha head [h, w], a transport [h, w, n] and a light [n, 3]: the
    photo-consistent rule weighted by alpha where the input is not saturated."""
    seen = srgb_decode((encoded + 1.0) * 0.5)
    weight = alpha * np.clip((2.0 * CLIPPED - 1.0 - encoded.max(axis=-1)) * 1e6, 0.0, 1.0)
    return _albedo(seen, transport @ light, weight)


def refine(decomposition, iterations: int = 8, ridge: float = RIDGE):
    """(decomposition with the refined light and its photo-consistent albedo, RefineReport).

    Only for networks whose albedo is photo-consistent and whose residual E is zero (the
    geometry-first model): for others the decomposition is returned unchanged ("off")."""
    d = decomposition
    if iterations == 0 or d.has_residual:
        return d, RefineReport((), 0, "off")
    light, report = refine_light(d.transport, d.photo_working, d.alpha, d.light, iterations, ridge)
    if report.iterations == 0:
        return d, report
    return d.with_light(light), report
