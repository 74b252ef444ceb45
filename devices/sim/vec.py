"""`Vec`: a point, direction or joint vector as the simulation takes it, a tuple or a numpy array."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

Vec = Sequence[float] | np.ndarray
