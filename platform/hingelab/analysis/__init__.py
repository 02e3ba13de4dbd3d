"""Analysis: success-rate tables and learning curves from datasets and runs (``hingelab report``).

One concern per module (data flows down the list):

- ``episode_table``: datasets -> one pandas row per episode (the index plus ``object_size``).
- ``wilson``: Wilson 95% intervals of success rates.
- ``success_tables``: rates by source / object / size, first-attempt and within-k rates,
  length and return distributions, failure reasons.
- ``learning_curves``: run folders' ``metrics.csv`` -> mean and band over seeds.
- ``plots``: the PNGs (matplotlib).
- ``documents``: report.md and report.html.
- ``report``: ``build_report(datasets, out, runs)`` ties them together and writes CSVs.
"""

from hingelab.analysis.episode_table import ReportInputError
from hingelab.analysis.report import Report, build_report
from hingelab.analysis.wilson import wilson_interval

__all__ = ["build_report", "Report", "ReportInputError", "wilson_interval"]
