"""Taxel-array tactile sensor models (thesis ch.3, 3.2: Xela uSkin and Contactile arrays).

A sensor is a planar grid of taxels on a pad. The pad frame ``pad`` has its origin at the grid
centre, x along the columns, y along the rows and z the pressing direction (out of the pad, towards
the touched object). Thesis ch.3: the Xela 4x4 array has a 4.7 mm taxel pitch; the 6x4 and 6x1
arrays share the Xela pitch; the Contactile array is 3x3 at 7 mm.

Shapes:
    TaxelSensor.taxel_positions() -> (rows * cols, 3) in the pad frame, metres, z = 0
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from vtlearn.validation import as_int, as_real


@dataclass(frozen=True)
class TaxelSensor:
    """A rows x cols taxel grid with ``pitch`` metres between neighbouring taxel centres."""

    name: str
    rows: int
    cols: int
    pitch: float

    def __post_init__(self):
        as_int(self.rows, "rows")
        as_int(self.cols, "cols")
        as_real(self.pitch, "pitch", low=0.0, open_low=True)

    @property
    def num_taxels(self) -> int:
        return self.rows * self.cols

    @property
    def extent(self) -> tuple[float, float]:
        """Pad size (x, y) in metres: one pitch beyond the outer taxel centres."""
        return self.cols * self.pitch, self.rows * self.pitch

    def taxel_positions(self) -> np.ndarray:
        """Taxel centres in the pad frame, row-major (row index varies slowest)."""
        xs = (np.arange(self.cols) - (self.cols - 1) / 2) * self.pitch
        ys = (np.arange(self.rows) - (self.rows - 1) / 2) * self.pitch
        gy, gx = np.meshgrid(ys, xs, indexing="ij")
        return np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)

    def housing_positions(self, subdivisions: int = 2) -> np.ndarray:
        """A denser grid over the whole pad, used to stop the rigid pad when it hits between taxels."""
        w, h = self.extent
        nx, ny = self.cols * subdivisions + 1, self.rows * subdivisions + 1
        gy, gx = np.meshgrid(np.linspace(-h / 2, h / 2, ny), np.linspace(-w / 2, w / 2, nx), indexing="ij")
        return np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)


SENSORS: dict[str, TaxelSensor] = {
    "xela_4x4": TaxelSensor("xela_4x4", 4, 4, 0.0047),
    "xela_6x4": TaxelSensor("xela_6x4", 6, 4, 0.0047),
    "xela_6x1": TaxelSensor("xela_6x1", 6, 1, 0.0047),
    "contactile_3x3": TaxelSensor("contactile_3x3", 3, 3, 0.007),
}

_SPEC = re.compile(r"^(\d+)x(\d+)@(\d+(?:\.\d*)?|\.\d+)mm$")


def get_sensor(spec: str | TaxelSensor) -> TaxelSensor:
    """A preset name (``xela_4x4``, ``xela_6x4``, ``xela_6x1``, ``contactile_3x3``) or ``RxC@Pmm``.

    ``RxC@Pmm`` is R rows by C columns (integers >= 1) at a pitch of P millimetres (> 0), e.g. ``"2x5@3mm"``
    or ``"4x4@4.7mm"``; anything else is a ``ValueError`` naming ``spec``.
    """
    if isinstance(spec, TaxelSensor):
        return spec
    if spec in SENSORS:
        return SENSORS[spec]
    m = _SPEC.match(str(spec))
    if m is None:
        raise ValueError(f"spec: unknown sensor {spec!r}; use one of {sorted(SENSORS)} or 'RxC@Pmm'")
    try:
        return TaxelSensor(str(spec), int(m.group(1)), int(m.group(2)), float(m.group(3)) / 1000.0)
    except ValueError as exc:
        raise ValueError(f"spec: bad sensor {spec!r} ({exc})") from None
