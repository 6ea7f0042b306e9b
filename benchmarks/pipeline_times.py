"""The time of each stage of a staged training run (``vla-gr train`` with ``pipeline.stages``):
a table of the stages done so far, from their ``stage.json`` records, and the JSON beside it.

    python benchmarks/pipeline_times.py --config-name recipe_vla_gr_cpu \
        pipeline.output_dir=<folder> --out benchmarks/results/rebuild_vla_gr_cpu

A stage without a record is listed as running (``started.json`` only) or not started.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from vla_gr.configs import load_config


def stage_rows(cfg) -> list[dict]:
    """One row per stage of the recipe: name, kind, state, seconds, attempts, product."""
    root = Path(cfg.pipeline.output_dir)
    rows = []
    for stage in cfg.pipeline.stages:
        folder = root / stage.name
        record = folder / "stage.json"
        row = {"stage": stage.name, "kind": stage.kind, "state": "not started"}
        if record.is_file():
            done = json.loads(record.read_text())
            row |= {"state": "done", "seconds": done["seconds"], "attempts": len(done["attempts"])}
        elif (folder / "started.json").is_file():
            row["state"] = "running or interrupted"
        rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| stage | kind | state | minutes |", "|---|---|---|---|"]
    for r in rows:
        minutes = f"{r['seconds'] / 60:.1f}" if "seconds" in r else ""
        lines.append(f"| {r['stage']} | {r['kind']} | {r['state']} | {minutes} |")
    done = sum(r.get("seconds", 0.0) for r in rows) / 60
    lines.append(f"\n{sum(r['state'] == 'done' for r in rows)} of {len(rows)} stages done, "
                 f"{done:.1f} min")  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config-name", required=True)
    parser.add_argument("overrides", nargs="*")
    parser.add_argument("--out", type=Path, default=None, help="write <out>.md and <out>.json")
    args = parser.parse_args(argv)
    _, cfg = load_config(args.config_name, args.overrides)
    rows = stage_rows(cfg)
    text = table(rows)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        command = " ".join(["python benchmarks/pipeline_times.py", *sys.argv[1:]])
        args.out.with_suffix(".md").write_text(f"# Stage times\n\n`{command}`\n\n{text}\n")
        args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
