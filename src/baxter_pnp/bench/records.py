"""Result rows of the trials and the soak: CSV cells, percentiles and numbers for the printed tables.

A row is a dict of one run's (or one soak cycle's) results; the units are in the keys (``_mm``, ``_s``,
``_mib``, ...). None stands for "not measured": an empty CSV cell, 'n/a' in a table.
"""
import csv

import numpy as np


def csv_value(value):
    """One CSV cell: floats to 4 significant digits (0.1 from 1e4 up), None as ''."""
    if isinstance(value, float):
        return f'{value:.4g}' if abs(value) < 1e4 else f'{value:.1f}'
    return '' if value is None else value


def write_rows(rows, fields, path):
    """``rows`` as a CSV file with a header of ``fields`` (missing keys as empty cells)."""
    with open(path, 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: csv_value(row.get(k)) for k in fields})


def percentile(values, q):
    """The ``q``-th percentile of ``values``, None if there are none."""
    return float(np.percentile(values, q)) if len(values) else None


def format_number(value, digits=1):
    """``value`` with ``digits`` decimals, 'n/a' for None."""
    return 'n/a' if value is None else f'{value:.{digits}f}'
