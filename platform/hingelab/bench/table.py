"""A benchmark's result table, printed and written under its folder (``analysis/bench/``: ``table_dir``)."""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

from hingelab.bench import table_dir
from hingelab.json_text import strict_dumps
from hingelab.provenance import code_version, machine


@dataclass
class BenchTable:
    """Rows of measured figures; ``ratios`` are ours / baseline from the same run; ``totals``, a benchmark's
    sums over its rows (a line of its own under the table)."""

    name: str
    title: str
    columns: list[str]
    rows: list[dict]
    ratios: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    config: dict = field(default_factory=dict)
    totals: dict = field(default_factory=dict)

    def markdown(self) -> str:
        def fmt(value) -> str:
            if isinstance(value, float):
                return f"{value:,.4g}" if abs(value) < 1e4 else f"{value:,.0f}"
            return " ".join(str(value).split()).replace("|", "\\|")  # one cell: no line breaks, no column breaks

        lines = [f"# {self.title}", ""]
        lines.append("| " + " | ".join(self.columns) + " |")
        lines.append("|" + "---|" * len(self.columns))
        for row in self.rows:
            lines.append("| " + " | ".join(fmt(row.get(c, "")) for c in self.columns) + " |")
        if self.totals:
            lines += ["", "Totals: " + ", ".join(f"{k} {fmt(v)}" for k, v in self.totals.items())]
        if self.ratios:
            lines += ["", "Ratios (measured in this one run):", ""]
            lines += [f"- {k}: {v:.3g}" for k, v in self.ratios.items()]
        if self.notes:
            lines += [""] + [f"- {n}" for n in self.notes]
        info = {**code_version(), **machine()}
        lines += ["", "Run: " + ", ".join(f"{k}={v}" for k, v in info.items())]
        return "\n".join(lines) + "\n"

    def write(self, out_dir: Path | None = None) -> tuple[Path, Path]:
        out_dir = Path(out_dir or table_dir(self.name))
        out_dir.mkdir(parents=True, exist_ok=True)
        md_path = out_dir / f"{self.name}.md"
        json_path = out_dir / f"{self.name}.json"
        md_path.write_text(self.markdown())
        payload = {
            "name": self.name,
            "title": self.title,
            "rows": self.rows,
            "ratios": self.ratios,
            **({"totals": self.totals} if self.totals else {}),
            "notes": self.notes,
            "config": self.config,
            "code": code_version(),
            "machine": machine(),
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        }
        json_path.write_text(strict_dumps(payload, json_path, indent=2) + "\n")
        return md_path, json_path
