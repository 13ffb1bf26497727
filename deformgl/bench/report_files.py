"""The machine-readable files of the benchmark reports (``--out DIR``): JSON and CSV, each
written atomically through :func:`deformgl.files.write_atomic` (temporary file, rename)."""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Sequence

from deformgl.files import write_atomic

__all__ = ["write_csv", "write_json"]


def write_json(path: str | os.PathLike[str], data: object) -> None:
    """``data`` as indented JSON."""
    text = json.dumps(data, indent=1)
    write_atomic(path, lambda stream: stream.write(text.encode()))


def write_csv(path: str | os.PathLike[str], records: Sequence[dict[str, object]],
              fields: Sequence[str] | None = None) -> None:
    """One line per record under a header of ``fields`` (default: the first record's keys);
    floats as Python prints them (shortest round-trip form)."""
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(fields if fields is not None else
                                                    (records[0] if records else [])))
    writer.writeheader()
    writer.writerows(records)
    write_atomic(path, lambda stream: stream.write(buffer.getvalue().encode()))
