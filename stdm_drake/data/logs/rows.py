"""`Rows`: a block of a log's rows in time order, what every reader yields to the importer."""
import dataclasses

import numpy as np


@dataclasses.dataclass
class Rows:
    """N consecutive rows of a log: t (N,) s (the row's stamp: its sampling instant); q (N, n) rad and v (N, n)
    rad/s measured; tau (N, m) N m commanded; the plan q_planned, v_planned, qdd_planned (N, n) rad, rad/s,
    rad/s² or None; mode (N,) int or None: a code of the robot's modes (a change starts a new trajectory);
    running (N,) bool or None: whether the robot runs normally at that row (other rows are left out); where
    (N,) int: the row's place in the log (file line, or message number) for error messages."""
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    where: np.ndarray
    q_planned: np.ndarray | None = None
    v_planned: np.ndarray | None = None
    qdd_planned: np.ndarray | None = None
    mode: np.ndarray | None = None
    running: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)

    @property
    def has_plan(self) -> bool:
        return self.q_planned is not None

    def take(self, index) -> "Rows":
        """The rows at `index` (a slice or an index array)."""
        return Rows(**{field.name: None if getattr(self, field.name) is None else getattr(self, field.name)[index]
                       for field in dataclasses.fields(self)})

    @staticmethod
    def concatenate(parts: list) -> "Rows":
        """One block of several in order (they agree on which fields they hold)."""
        return Rows(**{field.name: None if getattr(parts[0], field.name) is None else
                       np.concatenate([getattr(part, field.name) for part in parts])
                       for field in dataclasses.fields(Rows)})
