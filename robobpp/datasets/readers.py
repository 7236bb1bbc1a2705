"""Our own readers of the packsim data files (openpyxl for .xlsx, plain text for opai).

Each reader checks the layout it relies on (sheet, header names, value types) and raises
:class:`SourceFormatError` naming the file, row and column instead of guessing. Dimensions are returned as
given; the length ≥ width convention is applied by the importer.
"""

from __future__ import annotations

import io
import math
from datetime import datetime
from typing import Any

import numpy as np

from robobpp.datasets.errors import SourceFormatError

PICK_SHEET = "E1_E2"
PICK_COLUMNS = {
    "po": "PO Number",
    "pallet": "Pallet No",
    "station": "Case_pick_station",
    "start": "Case_pick_start_time",
    "finish": "Case_pick_finish_time",
    "material": "Material",
    "quantity": "Pick_quantity_cs",
    "length": "Length_cm",
    "width": "Width_cm",
    "height": "Height_cm",
    "mass": "Gross weight",
}
PICK_TIME_FORMAT = "%Y/%m/%d, %H:%M:%S"

SKU_SHEET = "道口物料清单"
SKU_COLUMNS = {
    "code": "商品code",
    "shipments": "3月份发货量（件）",
    "length": "尺寸（L）",
    "width": "尺寸（W）",
    "height": "尺寸（H）",
    "unit": "单位",
    "proportion": "占比",
}


def _sheet_rows(data: bytes, name: str, sheet: str) -> list[tuple[Any, ...]]:
    import openpyxl  # deferred: only the importer needs it

    try:
        workbook = openpyxl.load_workbook(io.BytesIO(data), read_only=True, data_only=True)
    except Exception as exc:  # openpyxl raises zipfile/KeyError/XML errors for damaged files
        raise SourceFormatError(f"{name}: not a readable .xlsx workbook ({exc})") from exc
    try:
        if sheet not in workbook.sheetnames:
            raise SourceFormatError(f"{name}: sheet {sheet!r} not found (sheets: {workbook.sheetnames})")
        return list(workbook[sheet].iter_rows(values_only=True))
    finally:
        workbook.close()


def _columns(header: tuple[Any, ...], wanted: dict[str, str], name: str) -> dict[str, int]:
    labels = [str(h).strip() if h is not None else "" for h in header]
    out = {}
    for key, label in wanted.items():
        if label not in labels:
            raise SourceFormatError(f"{name}: column {label!r} not found in header {labels}")
        out[key] = labels.index(label)
    return out


def _number(value: Any, name: str, row: int, column: str) -> float:
    """A finite number from a cell that may hold a number or its text (the split workbooks store text)."""
    if isinstance(value, bool):
        value = None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise SourceFormatError(f"{name} row {row}: {column} is not a number: {value!r}") from None
    if not math.isfinite(number):
        raise SourceFormatError(f"{name} row {row}: {column} is not finite: {value!r}")
    return number


def _positive(value: Any, name: str, row: int, column: str) -> float:
    number = _number(value, name, row, column)
    if number <= 0:
        raise SourceFormatError(f"{name} row {row}: {column} must be > 0, got {value!r}")
    return number


def read_pick_records(data: bytes, name: str) -> dict[str, np.ndarray]:
    """The Repetitive pick records in file order (which is time order; checked).

    Row numbers in errors are spreadsheet rows (header = row 1). The unnamed first column is a record id.
    """
    rows = _sheet_rows(data, name, PICK_SHEET)
    if len(rows) < 2:
        raise SourceFormatError(f"{name}: sheet {PICK_SHEET!r} has no records")
    cols = _columns(rows[0], PICK_COLUMNS, name)
    ids, starts, materials, stations, qty, dims, mass = [], [], [], [], [], [], []
    previous: tuple[Any, ...] | None = None
    duplicate = []
    for number, row in enumerate(rows[1:], start=2):
        ids.append(int(_number(row[0], name, number, "record id")))
        try:
            start = datetime.strptime(str(row[cols["start"]]).strip(), PICK_TIME_FORMAT)
        except ValueError:
            raise SourceFormatError(
                f"{name} row {number}: start time {row[cols['start']]!r} is not 'YYYY/MM/DD, HH:MM:SS'"
            ) from None
        starts.append(start.isoformat())
        materials.append(str(row[cols["material"]]))
        stations.append(str(row[cols["station"]]))
        quantity = _positive(row[cols["quantity"]], name, number, PICK_COLUMNS["quantity"])
        if quantity != int(quantity):
            raise SourceFormatError(f"{name} row {number}: pick quantity {quantity} is not a whole number")
        qty.append(int(quantity))
        dims.append(
            [_positive(row[cols[k]], name, number, PICK_COLUMNS[k]) for k in ("length", "width", "height")]
        )
        mass.append(_positive(row[cols["mass"]], name, number, PICK_COLUMNS["mass"]))
        # A record logged twice: every field but the record id repeats the previous row.
        body = tuple(str(v) for v in row[1:])
        duplicate.append(body == previous)
        previous = body
    if starts != sorted(starts):
        raise SourceFormatError(f"{name}: records are not in time order of {PICK_COLUMNS['start']}")
    return {
        "record_id": np.asarray(ids, dtype=np.int64),
        "start_time": np.asarray(starts, dtype=str),
        "material": np.asarray(materials, dtype=str),
        "station": np.asarray(stations, dtype=str),
        "quantity": np.asarray(qty, dtype=np.int64),
        "dims_raw": np.asarray(dims, dtype=np.float64),
        "mass": np.asarray(mass, dtype=np.float64),
        "duplicate": np.asarray(duplicate, dtype=bool),
    }


def read_record_ids(data: bytes, name: str) -> np.ndarray:
    """Only the record ids of a pick workbook (the authors' split files)."""
    rows = _sheet_rows(data, name, PICK_SHEET)
    _columns(rows[0], PICK_COLUMNS, name)
    return np.asarray([int(_number(r[0], name, i, "record id")) for i, r in enumerate(rows[1:], 2)], np.int64)


def read_skus(data: bytes, name: str) -> tuple[dict[str, np.ndarray], int]:
    """The Diverse SKUs with a size, and the number of all-zero rows left out (they have no size)."""
    rows = _sheet_rows(data, name, SKU_SHEET)
    if len(rows) < 2:
        raise SourceFormatError(f"{name}: sheet {SKU_SHEET!r} has no records")
    cols = _columns(rows[0], SKU_COLUMNS, name)
    codes, dims, shipments, proportion = [], [], [], []
    zero_rows = 0
    for number, row in enumerate(rows[1:], start=2):
        raw = [_number(row[cols[k]], name, number, SKU_COLUMNS[k]) for k in ("length", "width", "height")]
        if raw == [0.0, 0.0, 0.0]:
            zero_rows += 1
            continue
        for key, value in zip(("length", "width", "height"), raw, strict=True):
            _positive(value, name, number, SKU_COLUMNS[key])
        unit = str(row[cols["unit"]]).strip().lower()
        if unit != "cm":
            raise SourceFormatError(f"{name} row {number}: unit {row[cols['unit']]!r}, expected cm")
        codes.append(str(row[cols["code"]]).strip())
        dims.append(raw)
        shipments.append(int(_positive(row[cols["shipments"]], name, number, SKU_COLUMNS["shipments"])))
        proportion.append(_positive(row[cols["proportion"]], name, number, SKU_COLUMNS["proportion"]))
    if len(set(codes)) != len(codes):
        raise SourceFormatError(f"{name}: SKU codes are not unique")
    arrays = {
        "code": np.asarray(codes, dtype=str),
        "dims_raw": np.asarray(dims, dtype=np.float64),
        "shipments": np.asarray(shipments, dtype=np.int64),
        "proportion": np.asarray(proportion, dtype=np.float64),
    }
    return arrays, zero_rows


def read_panels(data: bytes, name: str) -> np.ndarray:
    """Long Board panels: one "L W H" line (cm) each; blank lines are ignored. Shape (n, 3)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SourceFormatError(f"{name}: not UTF-8 text ({exc})") from exc
    out = []
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != 3:
            raise SourceFormatError(f"{name} line {number}: expected 'L W H', got {line!r}")
        out.append([_positive(f, name, number, "LWH"[i]) for i, f in enumerate(fields)])
    if not out:
        raise SourceFormatError(f"{name}: no panels")
    return np.asarray(out, dtype=np.float64)
