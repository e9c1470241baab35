"""``lwbench label`` and ``lwbench train poconet`` (registered through lwbench_register_commands).

No ``from __future__ import annotations`` here: typer reads the parameter annotations at run
time, in this module's namespace.
"""

from pathlib import Path
from typing import Annotated

import typer


def register(cli: typer.Typer) -> None:
    """Add ``lwbench label`` and ``lwbench train poconet``."""

    @cli.command("label")
    def label(
        dataset: Annotated[str, typer.Argument(help="Registered dataset name or a path, with poses.")],
        out: Annotated[Path, typer.Option(help="Folder for labels/, counts/ and labels.json.")],
        dataset_param: Annotated[list[str], typer.Option("--dataset-param", help="KEY=VALUE.")] = [],  # noqa: B006
        frames: Annotated[int | None, typer.Option(help="Only the first N frames.", min=1)] = None,
        d_th: Annotated[float, typer.Option(help="Observation distance (m).")] = 0.1,
        r_th: Annotated[float, typer.Option(help="Share of high-priority points per scan.")] = 1 / 12,
        counts_from: Annotated[
            str,
            typer.Option(
                help="'all' scans of the sequence count observations (the "
                "paper's), or the 'mapping' drive only (what a robot has)."
            ),
        ] = "all",
    ) -> None:
        """PocoNet's training labels for a sequence with poses: observation counts, ground,
        Algorithm 1's dynamic threshold (high priority / low priority / ground)."""
        from lwbench import open_dataset

        from .labels import CLASSES, LabelSettings, LabelStore, label_dataset

        # An lwbench error raised here is printed by the CLI as one line, exit status 2.
        ds = open_dataset(dataset, dataset_param)
        idx = list(range(min(len(ds), frames) if frames else len(ds)))
        settings = LabelSettings(d_th=d_th, r_th=r_th, counts_from=counts_from)
        labels, counts = label_dataset(ds, idx, settings)
        LabelStore(out).write(ds, idx, labels, counts, settings)
        import numpy as np

        share = np.bincount(np.concatenate(labels), minlength=3) / sum(len(x) for x in labels)
        print(
            f"labelled {len(idx)} frames into {out}: "
            + ", ".join(f"{name} {100 * s:.1f} %" for name, s in zip(CLASSES, share, strict=True))
        )

    train_app = typer.Typer(help="Train a learned codec.", no_args_is_help=True)

    @train_app.command("poconet")
    def train_poconet(
        out: Annotated[Path, typer.Option(help="Run folder: checkpoints, curve.jsonl, labels.")] = Path(
            "poconet-train"
        ),
        epochs: Annotated[int, typer.Option(min=1)] = 4,
        drives: Annotated[
            str,
            typer.Option(
                help="Training drives SCENE:SEED[-LAST], comma-separated (each a mapping drive and another day's)."
            ),
        ] = "urban:30-51,indoor:30-31,tunnel:30-31",
        val_drives: Annotated[str, typer.Option(help="Validation drives, the same way.")] = "urban:20",
        frames: Annotated[int, typer.Option(help="Scans per drive (one day).", min=2)] = 40,
        margin: Annotated[
            int, typer.Option(help="Scans at each end of each drive that only count observations.", min=0)
        ] = 10,
        counts_from: Annotated[
            str, typer.Option(help="Labels: 'mapping' drive only (what a robot has) or 'all'.")
        ] = "mapping",
        sample: Annotated[str, typer.Option(help="'whole' sampled scans or 'crop's of them.")] = "whole",
        crop: Annotated[int, typer.Option(help="Points per training crop (--sample crop).", min=256)] = 8192,
        heading: Annotated[str, typer.Option(help="'jitter' (mirror + small yaw), 'full' yaw, or 'none'.")] = "jitter",
        budget_minutes: Annotated[float | None, typer.Option(help="Stop after this much training time.")] = None,
        device: Annotated[str, typer.Option(help="auto, cpu, cuda, cuda:N")] = "auto",
        threads: Annotated[int, typer.Option(help="Torch threads on the CPU.", min=1)] = 1,
        var_weight: Annotated[
            float, typer.Option(help="Weight of the codeword's variance term (0: the paper's loss alone).", min=0)
        ] = 0.0,
        export_to: Annotated[
            Path | None, typer.Option("--export", help="Also write the weights-only file here.")
        ] = None,
    ) -> None:
        """Train PocoNet on simulated two-day drives (resumes from OUT/last.pt)."""
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from .train import TrainConfig, export, parse_drives, train

        cfg = TrainConfig(
            out=str(out),
            epochs=epochs,
            drives=parse_drives(drives),
            val_drives=parse_drives(val_drives),
            frames=frames,
            margin=margin,
            counts_from=counts_from,
            sample=sample,
            crop=crop,
            heading=heading,
            device=device,
            threads=threads,
            var_weight=var_weight,
            time_budget_s=None if budget_minutes is None else 60 * budget_minutes,
        )
        with Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TimeElapsedColumn(),
        ) as bar:
            task = bar.add_task("training", total=None)
            last = train(cfg, lambda what, done, total: bar.update(task, description=what, completed=done, total=total))
        print(f"checkpoint {last}; learning curve {out / 'curve.jsonl'}")
        if export_to is not None:
            print(f"weights {export(last, export_to)}")

    cli.add_typer(train_app, name="train")
