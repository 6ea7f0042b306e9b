"""``vla-gr``: one entry point, one subcommand per app.

Every app subcommand takes ``--config-name NAME``, Hydra ``key=value`` overrides and
``--verbose``, and is also runnable as ``python -m vla_gr.<module>``; its ``--help`` lists the
keys it reads with their defaults and meanings, and ``--cfg job`` prints the resolved config
it would run with (an app module's ``compose_from_cli``, else ``load_config``). ``vla-gr store
verify PATH`` checks an episode store, ``vla-gr store copy SRC DST`` rewrites one,
``vla-gr store export-lerobot SRC DST`` writes one as a LeRobotDataset folder;
``vla-gr export SRC DST [key=value ...]`` writes a checkpoint for shipping;
``vla-gr export-onnx CHECKPOINT`` writes the ONNX export of its perception networks into it;
``vla-gr read TEXT [checkpoint=PATH]`` prints how an agent reads a request (exit 0 when
understood, 3 when not).
Errors a user causes end in one or two lines on stderr and exit code 2 (see
``vla_gr.configs.command``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence

from vla_gr import __version__
from vla_gr.configs.command import (
    add_hydra_arguments,
    add_verbose_argument,
    configure_logging,
    run_command,
    run_hydra_command,
)
from vla_gr.read_cli import add_read_arguments

# subcommand -> ("module:function", one-line help). Functions take (config_name, overrides).
COMMANDS: dict[str, tuple[str, str]] = {
    "collect": ("vla_gr.data.collect:run_from_cli", "run the expert and write a zarr dataset"),
    "demo": ("vla_gr.demo:run_from_cli", "run episodes, print metrics, write an HTML report"),
    "eval": ("vla_gr.evaluate:run_from_cli", "closed-loop evaluation of an agent: metrics, report"),
    "train": ("vla_gr.train:run_from_cli", "train the agent (single process or under torchrun)"),
}
#: Commands that read one text: name -> ("module:function", one-line help). Functions take
#: (text, settings): the text and its ``key=value`` settings.
TOOLS: dict[str, tuple[str, str]] = {
    "read": (
        "vla_gr.read_cli:run_from_cli",
        "read a request as the agent does: fields, confidences, understood or not",
    ),
}


def _resolve(target: str) -> Callable[[str, Sequence[str]], object]:
    module_name, func_name = target.split(":")
    return getattr(importlib.import_module(module_name), func_name)


def _compose_of(target: str):
    """The app's ``compose_from_cli`` (how it turns its arguments into a config), if any."""
    return getattr(importlib.import_module(target.split(":")[0]), "compose_from_cli", None)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vla-gr",
        description="VLA-GR: language-conditioned robot navigation policies.",
    )
    parser.add_argument("--version", action="version", version=f"vla-gr {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (_, help_text) in COMMANDS.items():
        p = sub.add_parser(
            name,
            help=help_text,
            description=help_text,
            add_help=False,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        add_hydra_arguments(p, name)
    store = sub.add_parser("store", help="inspect episode stores", description="episode stores")
    actions = store.add_subparsers(dest="action", metavar="ACTION", required=True)
    verify = actions.add_parser(
        "verify",
        help="check every chunk of a store (present, checksum, values); exit 1 when damaged",
    )
    verify.add_argument("path", help="the store folder (e.g. data/expert_train.zarr)")
    verify.add_argument(
        "--fast",
        action="store_true",
        help="skip decoding images: presence, checksums, actions and poses only",
    )
    add_verbose_argument(verify)
    copy = actions.add_parser(
        "copy",
        help="rewrite a store in the current format (adds checksums to a format-1 store)",
    )
    copy.add_argument("src", help="the store to read")
    copy.add_argument("dst", help="the new store (must not exist unless --overwrite)")
    copy.add_argument("--skip-damaged", action="store_true", help="copy only the intact episodes")
    copy.add_argument("--overwrite", action="store_true", help="replace dst if it exists")
    add_verbose_argument(copy)
    lerobot = actions.add_parser(
        "export-lerobot",
        help="write a store as a LeRobotDataset (v3.0) folder: parquet frames, PNG images, stats",
    )
    lerobot.add_argument("src", help="the store to read")
    lerobot.add_argument("dst", help="the dataset folder (must not exist unless --overwrite)")
    lerobot.add_argument(
        "--fps", type=int, default=None, help="frame rate (default: the store's control_hz)"
    )
    lerobot.add_argument("--overwrite", action="store_true", help="replace dst if it exists")
    add_verbose_argument(lerobot)
    export = sub.add_parser(
        "export",
        help="write a checkpoint for shipping (inference settings changed)",
        description="Copy checkpoint SRC to folder DST (replaced; files of its own are kept) "
        "without optimiser state, with inference-only settings changed.",
    )
    export.add_argument("src", help="a checkpoint folder, e.g. <run>/checkpoints/best")
    export.add_argument("dst", help="the folder to write")
    export.add_argument("overrides", nargs="*", help="inference settings, e.g. navigator.x=1")
    export.add_argument(
        "--fill-missing",
        action="store_true",
        help="write model keys the checkpoint lacks with this version's defaults",
    )
    export.add_argument(
        "--rename-keys",
        action="store_true",
        help="write renamed model keys by their new names (values unchanged), drop removed ones",
    )
    add_verbose_argument(export)
    onnx = sub.add_parser(
        "export-onnx",
        help="write the ONNX export of a checkpoint's perception networks into it",
        description="Export the goal head and the checks of checkpoint CHECKPOINT to ONNX "
        "(checked against PyTorch), listed in its manifest with the digest of their weights; "
        "model.perception.engine=onnxruntime runs them.",
    )
    onnx.add_argument("checkpoint", help="a checkpoint folder, e.g. checkpoints/vla_gr_cpu")
    add_verbose_argument(onnx)
    read_help = TOOLS["read"][1]
    read = sub.add_parser("read", help=read_help, description=f"{read_help}; exit 3 when not")
    add_read_arguments(read)
    return parser


def verify_store_command(path: str, deep: bool) -> int:
    """Print the health of the store at ``path``; 0 when healthy, 1 when damaged."""
    from vla_gr.data.verify import verify_store

    healthy, lines = verify_store(path, deep=deep)
    sys.stdout.write("\n".join(lines) + "\n")
    return 0 if healthy else 1


def copy_store_command(src: str, dst: str, skip_damaged: bool, overwrite: bool) -> int:
    """Copy ``src`` to a new store ``dst`` in the current format; 0 on success."""
    from vla_gr.data.verify import copy_store

    on_corrupt = "skip" if skip_damaged else "error"
    store = copy_store(src, dst, on_corrupt=on_corrupt, overwrite=overwrite)
    sys.stdout.write(f"{store.path}: {store.num_episodes} episodes, {store.num_frames} frames\n")
    return 0


def export_lerobot_command(src: str, dst: str, fps: int | None, overwrite: bool) -> int:
    """Export store ``src`` as a LeRobotDataset folder ``dst``; prints what it wrote; 0."""
    from vla_gr.data.lerobot_export import export_lerobot

    out = export_lerobot(src, dst, fps=fps, overwrite=overwrite)
    sys.stdout.write(
        f"{out.path}: LeRobotDataset v3.0, {out.episodes} episodes, {out.frames} frames, "
        f"{out.tasks} tasks at {out.fps} fps\n"
    )
    return 0


def export_command(
    src: str, dst: str, overrides: Sequence[str], fill_missing: bool, rename_keys: bool = False
) -> int:
    """Export checkpoint ``src`` to ``dst``; prints the folder written; 0 on success. A
    checkpoint that does not load (an old key name, a missing file) is the user's to fix: one
    line, no traceback."""
    from vla_gr.checkpoint import CheckpointError
    from vla_gr.errors import UserError
    from vla_gr.policy.export import export_pretrained

    try:
        out = export_pretrained(
            src, dst, overrides, fill_missing=fill_missing, rename_keys=rename_keys
        )
    except CheckpointError as err:
        raise UserError(str(err)) from err
    sys.stdout.write(f"{out}\n")
    return 0


def export_onnx_command(checkpoint: str) -> int:
    """Write the ONNX export of ``checkpoint``'s perception networks; prints its files; 0."""
    from vla_gr.checkpoint import CheckpointError
    from vla_gr.errors import UserError
    from vla_gr.policy.onnx_export import export_onnx

    try:
        files = export_onnx(checkpoint)
    except CheckpointError as err:
        raise UserError(str(err)) from err
    sys.stdout.write("".join(f"{f}\n" for f in files))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging()
    prog = f"vla-gr {args.command}"
    if args.command == "store" and args.action == "verify":
        return run_command(
            f"{prog} verify", verify_store_command, args.path, not args.fast, verbose=args.verbose
        )
    if args.command == "store" and args.action == "export-lerobot":
        return run_command(
            f"{prog} export-lerobot",
            export_lerobot_command,
            args.src,
            args.dst,
            args.fps,
            args.overwrite,
            verbose=args.verbose,
        )
    if args.command == "store":
        return run_command(
            f"{prog} copy",
            copy_store_command,
            args.src,
            args.dst,
            args.skip_damaged,
            args.overwrite,
            verbose=args.verbose,
        )
    if args.command == "export":
        return run_command(
            prog,
            export_command,
            args.src,
            args.dst,
            args.overrides,
            args.fill_missing,
            args.rename_keys,
            verbose=args.verbose,
        )
    if args.command == "export-onnx":
        return run_command(prog, export_onnx_command, args.checkpoint, verbose=args.verbose)
    if args.command in TOOLS:
        func = _resolve(TOOLS[args.command][0])
        return run_command(prog, func, args.text, args.settings, verbose=args.verbose)
    target = COMMANDS[args.command][0]
    compose = _compose_of(target) if args.cfg else None
    return run_hydra_command(prog, args, _resolve(target), compose)


if __name__ == "__main__":
    sys.exit(main())
