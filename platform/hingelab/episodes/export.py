"""Export a hingelab dataset to the layouts neighbouring libraries load, and import them back.

``export_dataset(dataset, "minari" | "lerobot", out)`` dispatches to one module per format:

- ``export_minari.py``: a Minari 0.5 dataset (``OUT/NAMESPACE/NAME-vN/data/main_data.hdf5`` and
  ``metadata.json``) that ``minari.load_dataset("NAMESPACE/NAME-vN")`` opens with
  ``MINARI_DATASETS_PATH=OUT``;
- ``export_lerobot.py``: a LeRobotDataset v3.0 folder (``OUT/meta/info.json``, ``stats.json``,
  ``tasks.parquet``, ``meta/episodes/...``, ``data/chunk-000/file-000.parquet``);
- ``export_source.py``: what both take from an episode (the ``/step`` arrays, the tool clouds
  aligned to the observations by log time, what is skipped and why), and the way back;
- ``export_output.py``: the output folder, written atomically (a failed export leaves nothing
  behind), and ``ExportResult``.
"""

from __future__ import annotations

from hingelab.episodes.errors import DatasetError
from hingelab.episodes.export_lerobot import export_lerobot, import_lerobot
from hingelab.episodes.export_minari import export_minari, import_minari
from hingelab.episodes.export_output import ExportResult, atomic_folder

FORMATS = ("minari", "lerobot")


def export_dataset(dataset, fmt: str, out, dataset_id: str | None = None, progress: bool = False) -> ExportResult:
    """Export ``dataset`` (a ``Dataset``) as ``fmt`` into ``out`` (see the format modules)."""
    if fmt == "minari":
        return export_minari(dataset, out, dataset_id=dataset_id, progress=progress)
    if dataset_id is not None:
        raise DatasetError("--dataset-id names a Minari dataset; a LeRobot export is the --out folder itself")
    if fmt == "lerobot":
        return export_lerobot(dataset, out, progress=progress)
    raise DatasetError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")


__all__ = ["ExportResult", "FORMATS", "atomic_folder", "export_dataset", "export_minari", "export_lerobot",
           "import_minari", "import_lerobot"]
