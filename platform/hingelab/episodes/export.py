"""Export a hingelab dataset to the layouts neighbouring libraries load, and import them back.

``export_dataset(dataset, FORMAT, out)`` dispatches to the exporter registered under FORMAT
(``register_exporter``; ``hingelab.ros2.bag_export`` registers ``ros2``), one module per format:

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

# name -> export(dataset, out, dataset_id=None, progress=False) -> ExportResult; a layer above episodes adds its
# format with register_exporter (hingelab.ros2.bag_export adds "ros2")
EXPORTERS: dict = {}


def register_exporter(name: str, export) -> None:
    EXPORTERS[name] = export


def _lerobot(dataset, out, dataset_id=None, progress=False) -> ExportResult:
    if dataset_id is not None:
        raise DatasetError("--dataset-id names a Minari dataset; a LeRobot export is the --out folder itself")
    return export_lerobot(dataset, out, progress=progress)


register_exporter("minari", export_minari)
register_exporter("lerobot", _lerobot)


def export_dataset(dataset, fmt: str, out, dataset_id: str | None = None, progress: bool = False) -> ExportResult:
    """Export ``dataset`` (a ``Dataset``) as ``fmt`` (a name of ``EXPORTERS``) into ``out``."""
    if fmt not in EXPORTERS:
        raise DatasetError(f"unknown export format {fmt!r}; choose one of {', '.join(EXPORTERS)}")
    return EXPORTERS[fmt](dataset, out, dataset_id=dataset_id, progress=progress)


__all__ = ["ExportResult", "EXPORTERS", "atomic_folder", "export_dataset", "export_minari", "export_lerobot",
           "import_minari", "import_lerobot", "register_exporter"]
