"""The generator's own instructions of ``test`` 0-999 and ``val`` 0-999 with their fields
(what the reader must read from them: the agent read exactly these before the reader).

    python benchmarks/language/template_readings.py \
        --out benchmarks/language/template_instructions.json

Writes {"<split>-<index>": {"instruction", "fields"}} (an index whose house hosts no episode
is skipped, as the environment skips it).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from vla_gr.envs.episodes import NoEpisodeError, sample_episode
from vla_gr.envs.instructions import parse_instruction


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--count", type=int, default=1000)
    args = parser.parse_args()
    out = {}
    for split in ("test", "val"):
        for index in range(args.count):
            try:
                spec = sample_episode(split, index)
            except NoEpisodeError:
                continue
            out[f"{split}-{index}"] = {
                "instruction": spec.instruction,
                "fields": parse_instruction(spec.instruction),
            }
    Path(args.out).write_text(json.dumps(out, indent=0, sort_keys=True) + "\n")
    print(f"{len(out)} instructions -> {args.out}")


if __name__ == "__main__":
    main()
