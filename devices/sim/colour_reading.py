"""What the lab's colour sensor (a TCS34725 with its white LED) reports for a surface colour, without a
physics world: the fleet's colour sensors (devices.sim.stations) report it in processes that load no
pybullet; devices.sim.sensors casts the ray that finds the surface."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # numpy's type: the fleet's processes load no numpy for it
    from devices.sim.vec import Vec


@dataclass(frozen=True)
class ColorReading:
    color: list[int]      # r, g, b 0..255
    lux: float            # 100..14000
    temperature: float    # K, 1000..20000


NO_OBJECT = ColorReading([0, 0, 0], 100.0, 6500.0)


def reading_of(rgb: Vec) -> ColorReading:
    """What the sensor reports for a surface of sRGB colour `rgb` (each 0..1)."""
    r, g, b = (min(max(float(v), 0.0), 1.0) for v in rgb)
    lin = [v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4 for v in (r, g, b)]
    x_ = 0.4124 * lin[0] + 0.3576 * lin[1] + 0.1805 * lin[2]
    y_ = 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]
    z_ = 0.0193 * lin[0] + 0.1192 * lin[1] + 0.9505 * lin[2]
    total = x_ + y_ + z_
    if total <= 1e-9:
        cct = 1000.0
    else:
        n = (x_ / total - 0.3320) / (0.1858 - y_ / total)
        cct = 449.0 * n ** 3 + 3525.0 * n ** 2 + 6823.3 * n + 5520.33
    return ColorReading(color=[round(255 * v) for v in (r, g, b)],
                        lux=round(100.0 + 13900.0 * y_, 1),
                        temperature=round(min(max(cct, 1000.0), 20000.0), 1))
