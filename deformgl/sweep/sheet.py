"""A sweep's table (CSV, JSON) and contact sheet (PNG: each variant's image, labelled, failed
variants as a grey panel with their error), written together and atomically."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from deformgl.files import OutputSet, read_png, write_atomic, write_png_atomic

__all__ = ["COLUMNS", "contact_sheet", "write_tables"]

#: The table's columns after the variant, its status, error and overrides.
COLUMNS = ("mesh", "nodes", "springs", "integrator", "backend", "mapping", "steps", "dt_s", "substeps",
           "simulated_time_s", "converged", "wall_time_s", "task_wall_time_s", "worker_pid", "device", "renderer")


def _rows(records: list[dict[str, Any]]) -> tuple[list[str], list[list[Any]]]:
    keys: list[str] = []
    for r in records:
        for k in r.get("overrides", {}):
            if k not in keys:
                keys.append(k)
    header = ["variant", "status", "error", *keys, *COLUMNS]
    rows = [[r.get("variant"), r.get("status"), r.get("error", ""), *(r.get("overrides", {}).get(k) for k in keys),
             *(r.get(c) for c in COLUMNS)] for r in records]
    return header, rows


def contact_sheet(records: list[dict[str, Any]], folder: Path, *, cell: int = 200, columns: int = 4) -> np.ndarray:
    """Thumbnails of each variant's PNG (``folder/NAME.png``), ``cell`` pixels wide, labelled."""
    from PIL import Image, ImageDraw

    cols = max(1, min(columns, len(records)))
    rows = (len(records) + cols - 1) // cols
    label_h, cell_h = 26, int(cell * 0.75)
    sheet = Image.new("RGB", (cols * cell, rows * (cell_h + label_h)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for i, r in enumerate(records):
        x, y = (i % cols) * cell, (i // cols) * (cell_h + label_h)
        png = folder / f"{r['variant']}.png"
        if r.get("status") == "ok" and png.is_file():
            thumb = Image.fromarray(read_png(png)).convert("RGB")
            thumb.thumbnail((cell - 4, cell_h - 4))
            sheet.paste(thumb, (x + (cell - thumb.width) // 2, y + (cell_h - thumb.height) // 2))
        else:
            draw.rectangle((x + 2, y + 2, x + cell - 3, y + cell_h - 3), fill=(200, 200, 200))
            draw.text((x + 6, y + 6), str(r.get("status", "?")), fill=(150, 0, 0))
            text = str(r.get("error", ""))
            for j in range(0, min(len(text), 150), 30):
                draw.text((x + 6, y + 20 + j // 30 * 12), text[j:j + 30], fill=(60, 60, 60))
        label = f"{r['variant']}: {r.get('label', '')}"
        draw.text((x + 4, y + cell_h + 2), label[:34], fill=(0, 0, 0))
        draw.text((x + 4, y + cell_h + 13), label[34:68], fill=(0, 0, 0))
    return np.asarray(sheet)


def write_tables(records: list[dict[str, Any]], folder: Path, *, sheet: bool = True) -> list[Path]:
    """``folder/sweep.csv``, ``sweep.json`` and (with ``sheet``) ``sweep.png``, all or none."""
    paths = [folder / "sweep.csv", folder / "sweep.json"] + ([folder / "sweep.png"] if sheet else [])
    header, rows = _rows(records)
    text = io.StringIO()
    writer = csv.writer(text)
    writer.writerow(header)
    writer.writerows(rows)
    with OutputSet(paths):
        write_atomic(paths[0], lambda s: s.write(text.getvalue().encode()))
        payload = json.dumps(records, indent=2, default=str) + "\n"
        write_atomic(paths[1], lambda s: s.write(payload.encode()))
        if sheet:
            write_png_atomic(paths[2], contact_sheet(records, folder))
    return paths
