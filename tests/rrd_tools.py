"""Reading a Rerun 0.41 recording back in tests (`rerun.chunk.RrdReader` + pyarrow)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
from rerun.chunk import RrdReader


def read_rows(path: Path, entity: str) -> list[dict]:
    """Every row logged to ``entity`` as a dict {column name: value}, in file order.

    Columns are named like ``Transform3D:translation`` (each value a list of instances);
    timeline columns ``tick`` and ``sim_time`` become ints (``sim_time`` in nanoseconds).
    Static rows have no timeline columns.
    """
    entity = "/" + entity.lstrip("/")
    rows: list[dict] = []
    for chunk in RrdReader(str(path)).stream().filter(content=entity).to_chunks():
        table = pa.Table.from_batches([chunk.to_record_batch()])
        columns = {}
        for name in table.column_names:
            column = table.column(name)
            if pa.types.is_timestamp(column.type) or pa.types.is_duration(column.type):
                column = column.cast(pa.int64())
            columns[name] = column.to_pylist()
        rows.extend({k: v[i] for k, v in columns.items()} for i in range(table.num_rows))
    return rows


def mat3x3(flat_column_major) -> np.ndarray:
    """Rerun stores 3x3 matrices column-major: back to a numpy (3, 3)."""
    return np.asarray(flat_column_major, dtype=np.float64).reshape(3, 3).T
