"""Whole experiments behind ``scapo bench``: the paper's tables regenerated with our methods.

- :mod:`scapo.bench.cells`: one cell (method x category x training seed x ablation), computed once and
  kept with its record in the bench work folder.
- :mod:`scapo.bench.experiments`: Tables 1, 2 (real-world style) and 3, each a frozen :class:`TableSpec` in
  :data:`TABLES` (categories, protocol, data settings, rows), made by :func:`run_table`: their cells, dry-run
  plan, tables and figures.
- :mod:`scapo.bench.choose`: choices of an option value on the validation split.
- :mod:`scapo.bench.archive`: the cells archive (records, per-sample metrics, pinned datasets) that outlives a machine.
- :mod:`scapo.bench.ladder`: the canonical-frame diagnosis ladder; :mod:`scapo.bench.compute`: accuracy against
  training compute on one of its rungs.
- :mod:`scapo.bench.perf`: speed (generation, training, inference); :mod:`scapo.bench.demo`: the demo;
  :mod:`scapo.bench.viz`: figures; :mod:`scapo.bench.viewer`: the browser viewer; :mod:`scapo.bench.headline`: the
  README's block of headline numbers, generated from ``results/``.
"""

from scapo.bench.cells import Cell, cell_status, compute_cell, evaluator_fingerprint, method_preset
from scapo.bench.choose import CRITERIA, choose_on_val
from scapo.bench.experiments import (
    TABLE1_CATEGORIES,
    TABLE2_CATEGORIES,
    TABLES,
    BenchOptions,
    TableSpec,
    dataset_dir,
    parse_category_seeds,
    plan,
    run_table,
    run_table1,
    run_table2,
    run_table3,
    table1_cells,
    table2_cells,
    table3_cells,
)

__all__ = ["CRITERIA", "TABLE1_CATEGORIES", "TABLE2_CATEGORIES", "TABLES", "BenchOptions", "Cell", "TableSpec",
           "cell_status", "choose_on_val", "compute_cell", "dataset_dir", "evaluator_fingerprint", "method_preset",
           "parse_category_seeds", "plan", "run_table", "run_table1", "run_table2", "run_table3", "table1_cells",
           "table2_cells", "table3_cells"]
