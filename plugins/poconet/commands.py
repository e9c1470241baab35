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
    ) -> None:
        """PocoNet's training labels for a sequence with poses: observation counts, ground,
        Algorithm 1's dynamic threshold (high priority / low priority / ground)."""
        from lwbench import open_dataset

        from .labels import CLASSES, LabelSettings, LabelStore, label_dataset

        # An lwbench error raised here is printed by the CLI as one line, exit status 2.
        ds = open_dataset(dataset, dataset_param)
        idx = list(range(min(len(ds), frames) if frames else len(ds)))
        settings = LabelSettings(d_th=d_th, r_th=r_th)
        labels, counts = label_dataset(ds, idx, settings)
        LabelStore(out).write(ds, idx, labels, counts, settings)
        import numpy as np

        share = np.bincount(np.concatenate(labels), minlength=3) / sum(len(x) for x in labels)
        print(f"labelled {len(idx)} frames into {out}: " + ", ".join(
            f"{name} {100 * s:.1f} %" for name, s in zip(CLASSES, share, strict=True)))

    train_app = typer.Typer(help="Train a learned codec.", no_args_is_help=True)

    @train_app.command("poconet")
    def train_poconet(
        out: Annotated[Path, typer.Option(help="Run folder: checkpoints, curve.jsonl, labels.")] = Path(
            "poconet-train"
        ),
        epochs: Annotated[int, typer.Option(min=1)] = 12,
        frames: Annotated[int, typer.Option(help="Scans per training drive (1 m apart).", min=2)] = 120,
        margin: Annotated[int, typer.Option(help="Scans at each end of a drive that only count observations.",
                                            min=0)] = 25,
        seeds: Annotated[str, typer.Option(help="Training sim seeds, comma-separated.")] = "10,11,12,13",
        crop: Annotated[int, typer.Option(help="Points per training crop.", min=256)] = 8192,
        budget_minutes: Annotated[float | None, typer.Option(help="Stop after this much training time.")] = None,
        device: Annotated[str, typer.Option(help="auto, cpu, cuda, cuda:N")] = "auto",
        export_to: Annotated[Path | None, typer.Option("--export", help="Also write the weights-only file here.")]
        = None,
    ) -> None:
        """Train PocoNet on simulated streets (resumes from OUT/last.pt)."""
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from .train import TrainConfig, export, train

        cfg = TrainConfig(
            out=str(out), epochs=epochs, frames=frames, margin=margin, crop=crop, device=device,
            train_seeds=tuple(int(s) for s in seeds.split(",")),
            time_budget_s=None if budget_minutes is None else 60 * budget_minutes,
        )
        with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                      TimeElapsedColumn()) as bar:
            task = bar.add_task("training", total=None)
            last = train(cfg, lambda what, done, total: bar.update(task, description=what, completed=done,
                                                                    total=total))
        print(f"checkpoint {last}; learning curve {out / 'curve.jsonl'}")
        if export_to is not None:
            print(f"weights {export(last, export_to)}")

    cli.add_typer(train_app, name="train")
