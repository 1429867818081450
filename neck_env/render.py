"""Drawing of the neck for ``render_mode="rgb_array"`` / ``"human"``.

Frame: ``(320, 640, 3)`` uint8. Left: oblique 3D view of the base plate, the bent backbone
(constant-curvature arc), the head mount, the six springs (coloured blue -> red by temperature,
drawn thick while current flows) and the target pose as a green ghost backbone. Right: top view
of the tilt plane (rings every 10 deg): the true tilt (black dot), the measured tilt (grey), the
target (green ring), the muscles at their azimuths coloured by temperature, and the energy
budget left as a bar along the bottom.

Plain numpy rasterising (no plotting library) keeps a frame at a few milliseconds.
"""

from __future__ import annotations

import math

import numpy as np

from .params import NeckParams
from .physics import layout as L
from .physics.backbone import backbone_points, head_rotation

H, W = 320, 640
_BG = (250, 250, 247)
_INK = (40, 40, 40)
_GREEN = (30, 160, 60)


def _temp_colour(T: float) -> tuple[int, int, int]:
    a = min(max((T - 25.0) / 100.0, 0.0), 1.0)
    return int(40 + 215 * a), int(90 * (1 - a) + 40), int(220 * (1 - a) + 30)


class _Canvas:
    def __init__(self):
        self.img = np.empty((H, W, 3), dtype=np.uint8)
        self.img[:] = _BG

    def dots(self, us: np.ndarray, vs: np.ndarray, colour, radius: int = 1) -> None:
        us = np.rint(us).astype(int)
        vs = np.rint(vs).astype(int)
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                if dx * dx + dy * dy > radius * radius + radius:
                    continue
                y, x = vs + dy, us + dx
                ok = (y >= 0) & (y < H) & (x >= 0) & (x < W)
                self.img[y[ok], x[ok]] = colour

    def polyline(self, pts: np.ndarray, colour, radius: int = 1) -> None:
        for a, b in zip(pts[:-1], pts[1:]):
            n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1]))) + 1
            t = np.linspace(0.0, 1.0, n)
            self.dots(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), colour, radius)

    def circle(self, cx: float, cy: float, r: float, colour, radius: int = 1, filled=False) -> None:
        if filled:
            y, x = np.ogrid[:H, :W]
            self.img[(x - cx) ** 2 + (y - cy) ** 2 <= r * r] = colour
            return
        a = np.linspace(0, 2 * np.pi, max(int(2 * np.pi * r), 8))
        self.dots(cx + r * np.cos(a), cy + r * np.sin(a), colour, radius)


class NeckRenderer:
    def __init__(self, params: NeckParams, human: bool = False):
        self.params = params
        self.human = human
        self._fig = None
        self.scale = 170.0 / params.backbone.length_m  # pixels per metre: backbone = 170 px

    def _project(self, p: np.ndarray) -> np.ndarray:
        """Oblique projection of world points (..., 3) into the left panel's pixels."""
        s = self.scale
        u = 160 + s * (p[..., 0] * 0.87 - p[..., 1] * 0.5)
        v = 250 - s * (p[..., 2] + 0.35 * (p[..., 0] * 0.5 + p[..., 1] * 0.87))
        return np.stack([u, v], axis=-1)

    def draw(self, core, i: int) -> np.ndarray:
        p = self.params
        cv = _Canvas()
        c, x = core.consts[i], core.x[i]
        q = x[L.S_Q:L.S_Q + 3]
        temps = x[L.S_T:L.S_T + 3]
        amps = core.out[i, L.O_CURRENT:L.O_CURRENT + 3]
        l = p.backbone.length_m
        # Base plate and target ghost.
        a = np.linspace(0, 2 * np.pi, 60)
        rb = p.muscles.base_radius_m * 1.6
        cv.polyline(self._project(np.stack([rb * np.cos(a), rb * np.sin(a), 0 * a], -1)), _INK, 1)
        tq = np.array([np.radians(core.target[i, 0]), np.radians(core.target[i, 1]), 0.0])
        cv.polyline(self._project(backbone_points(tq[None], l)[0]), _GREEN, 1)
        # Backbone, head mount, springs.
        spine = backbone_points(q[None], l)[0]
        cv.polyline(self._project(spine), _INK, 3)
        R = head_rotation(q[None])[0]
        tip = spine[-1]
        rh = p.muscles.head_radius_m
        ring = tip[:, None] + R @ np.stack([1.3 * rh * np.cos(a), 1.3 * rh * np.sin(a), 0 * a])
        cv.polyline(self._project(ring.T), _INK, 2)
        anchors = c[L.ANCHOR:L.ANCHOR + 18].reshape(3, 2, 3)
        for k in range(3):
            psi = c[L.PSI + k]  # R already holds the twist
            tendon = tip + R @ np.array([rh * math.cos(psi), rh * math.sin(psi), 0.0])
            col = _temp_colour(temps[k])
            for s in range(2):
                cv.polyline(self._project(np.stack([anchors[k, s], tendon])), col,
                            3 if amps[k] > 1e-6 else 1)
        # Top view of the tilt plane.
        cx, cy, per_deg = 480.0, 150.0, 4.0
        for ring_deg in (10, 20, 30):
            cv.circle(cx, cy, ring_deg * per_deg, (200, 200, 200), 0)
        for k in range(3):
            psi = c[L.PSI + k]
            cv.circle(cx + 36 * per_deg * math.cos(psi), cy - 36 * per_deg * math.sin(psi), 9,
                      _temp_colour(temps[k]), filled=True)
        tx, ty = core.target[i]
        cv.circle(cx + tx * per_deg, cy - ty * per_deg, 7, _GREEN, 2)
        mx, my = core.obs[i, 0], core.obs[i, 1]
        cv.circle(cx + mx * per_deg, cy - my * per_deg, 4, (150, 150, 150), filled=True)
        bx, by = math.degrees(q[0]), math.degrees(q[1])
        cv.circle(cx + bx * per_deg, cy - by * per_deg, 5, _INK, filled=True)
        # Energy left.
        frac = float(core.obs[i, 7])
        cv.img[300:310, 340:620] = (225, 225, 225)
        cv.img[300:310, 340:340 + int(280 * frac)] = (240, 170, 40)
        if self.human:
            self._show(cv.img)
        return cv.img

    def _show(self, img: np.ndarray) -> None:
        import matplotlib.pyplot as plt

        if self._fig is None:
            plt.ion()
            self._fig, ax = plt.subplots(figsize=(8, 4))
            ax.axis("off")
            self._im = ax.imshow(img)
        else:
            self._im.set_data(img)
        self._fig.canvas.draw_idle()
        plt.pause(0.001)

    def close(self) -> None:
        if self._fig is not None:
            import matplotlib.pyplot as plt

            plt.close(self._fig)
            self._fig = None
