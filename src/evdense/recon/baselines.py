"""Classical intensity reconstruction that needs no weights: leaky integration and the high-pass filter.

Both estimate the per-pixel log intensity ``L(x, t)`` from events, each event adding
``+C_on`` or ``-C_off`` (the contrast thresholds) at its pixel, and solve the same equation
(Scheerlinck, Barnes, Mahony, "Continuous-time intensity estimation using event cameras",
ACCV 2018)::

    dL/dt = E(x, t) - alpha * (L - L_ref)

with ``E`` the train of events, ``alpha`` a cut-off frequency (rad/s) and ``L_ref`` a reference
log image (zero, or the log of the last conventional frame for the complementary filter).
``alpha = 0`` is direct integration; ``alpha > 0`` forgets old events (a high-pass filter),
which removes the drift of integration at the cost of fading static edges.

Between two output times ``t0 < t1``, with ``L_ref`` constant, the exact solution is::

    L(t1) = L_ref + (L(t0) - L_ref) * exp(-alpha (t1 - t0)) + sum_k c_k * exp(-alpha (t1 - t_k))

summed over the events ``k`` of each pixel in ``(t0, t1]``. It is linear in the events, so a
whole window is evaluated with one weighted ``np.bincount`` and no per-event loop: the result
equals the event-by-event recursion ``L <- L * exp(-alpha dt) + c_k`` up to float rounding (not an
approximation). Not implemented: the paper's per-pixel adaptive gain that lowers ``alpha`` where
the reference frame is saturated (our reference is optional and 8-bit).
"""

from __future__ import annotations

import numpy as np

from evdense.events.container import Events


class LogIntensityFilter:
    """Per-pixel log-intensity estimate driven by events (integration, high-pass, complementary).

    Args:
        height, width: sensor size in pixels.
        cutoff_rad_s: ``alpha``, the cut-off frequency in rad/s (0 = pure integration).
        contrast_on, contrast_off: log-intensity step of a positive / negative event.
        t_us: time of the initial state (microseconds); the state starts at ``L_ref`` (zeros).
    """

    def __init__(
        self,
        height: int,
        width: int,
        cutoff_rad_s: float = 0.0,
        contrast_on: float = 0.2,
        contrast_off: float = 0.2,
        t_us: int = 0,
    ) -> None:
        if cutoff_rad_s < 0:
            raise ValueError(f"cutoff_rad_s must be >= 0, got {cutoff_rad_s}")
        if contrast_on <= 0 or contrast_off <= 0:
            raise ValueError(f"contrasts must be > 0, got {contrast_on}, {contrast_off}")
        self.height, self.width = int(height), int(width)
        self.alpha = float(cutoff_rad_s)
        self.contrast_on = float(contrast_on)
        self.contrast_off = float(contrast_off)
        self.t_us = int(t_us)
        self.reference = np.zeros((self.height, self.width), dtype=np.float64)
        self.log_image = np.zeros((self.height, self.width), dtype=np.float64)

    def set_reference(self, log_reference: np.ndarray) -> None:
        """Use ``log_reference`` (H, W) as ``L_ref`` from now on (complementary filter)."""
        if log_reference.shape != (self.height, self.width):
            raise ValueError(
                f"reference of shape {log_reference.shape}, expected {(self.height, self.width)}"
            )
        self.reference = np.asarray(log_reference, dtype=np.float64)

    def advance(self, events: Events, t_us: int) -> np.ndarray:
        """Take in ``events`` (all with ``self.t_us <= t <= t_us``) and move the state to ``t_us``.

        Returns the log-intensity image (H, W) at ``t_us`` (a view of the state: copy it to keep it).
        """
        t_us = int(t_us)
        if t_us < self.t_us:
            raise ValueError(f"cannot go back in time from {self.t_us} us to {t_us} us")
        n = len(events)
        if n and (int(events.t[0]) < self.t_us or int(events.t[-1]) > t_us):
            raise ValueError(
                f"events from {int(events.t[0])} to {int(events.t[-1])} us lie outside "
                f"[{self.t_us}, {t_us}] us"
            )
        c = np.where(events.p > 0, self.contrast_on, -self.contrast_off)
        if self.alpha > 0:
            decay = np.exp(-self.alpha * (t_us - self.t_us) * 1e-6)
            self.log_image -= self.reference
            self.log_image *= decay
            self.log_image += self.reference
            c = c * np.exp(-self.alpha * (t_us - events.t) * 1e-6)
        if n:
            flat = events.y.astype(np.int64) * self.width + events.x
            inc = np.bincount(flat, weights=c, minlength=self.height * self.width)
            self.log_image += inc.reshape(self.height, self.width)
        self.t_us = t_us
        return self.log_image
