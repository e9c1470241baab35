"""``lwbench fuzz``: crafted payloads against the installed decoders, counted (docs/hostile.md).

Each codec's seed payloads -- its declared parameter choices on four small scans, at the codec's
own fast settings (:meth:`lwbench.Codec.test_params`) -- are mutated ``--cases`` times with a
seeded RNG and decoded in one :class:`lwbench.fuzz.DecodeServer` (a child process: one thread, a
memory ceiling, a per-case timeout). The table counts what came back; a case that broke the
contract (anything but a cloud or a ``PayloadError``, an absurd cloud, over a second of CPU or
512 MB) is an *escape*, and any escape makes the exit status 1, so that CI can gate on it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from .app import app, registry
from .listing import PANEL
from .options import CODECS, OUTPUT, words
from .output import console, err_console, escape, progress, writable_folder

__all__ = ["fuzz", "fuzz_settings"]

ESCAPE_STATUS = 1  # a case broke the contract (2 stays the user error's status)


def fuzz_settings(classes: dict, params: list[str]) -> dict[str, dict]:
    """Per codec, the settings its seed payloads are encoded with: its ``test_params()`` with
    ``--param CODEC.KEY=VALUE`` (``KEY=VALUE`` when one codec is fuzzed) over them, each value
    read as the codec declares the parameter."""
    from lwbench.errors import ParameterError

    out = {name: dict(cls.test_params()) for name, cls in classes.items()}
    for word in params:
        target, sep, text = word.partition("=")
        owner, dot, key = target.partition(".")
        if not dot:
            if len(classes) != 1:
                raise ParameterError(f"--param {word!r}: write CODEC.KEY=VALUE when fuzzing several codecs")
            owner, key = next(iter(classes)), target
        owner, key = owner.strip(), key.strip()
        if not sep or not key:
            raise ParameterError(f"--param must look like CODEC.KEY=VALUE, got {word!r}")
        if owner not in classes:
            raise ParameterError(f"--param {word!r} is for codec {owner!r}, which is not fuzzed here "
                                 f"({', '.join(classes)})")
        declared = {p.name: p for p in classes[owner].all_params()}
        if key not in declared:
            raise ParameterError(f"--param {word!r}: {owner} has no parameter {key!r}; known: "
                                 f"{', '.join(sorted(declared)) or '(none)'}")
        try:
            out[owner][key] = declared[key].parse(text)
        except ParameterError as exc:
            raise ParameterError(f"--param {word!r}: {exc}") from None
    return out


@app.command(rich_help_panel=PANEL)
def fuzz(
    codecs: Annotated[list[str] | None, typer.Argument(
        metavar="CODEC", help="Codecs to fuzz (default: every installed one).", show_default=False)] = None,
    cases: Annotated[int, typer.Option("--cases", min=1, help="Mutated payloads per codec.")] = 4000,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the mutations.")] = 0,
    seconds: Annotated[float | None, typer.Option(
        "--seconds", min=0, help="Stop a codec's campaign after this long (fewer cases).")] = None,
    param: Annotated[list[str] | None, typer.Option(
        "--param", rich_help_panel=CODECS,
        help="CODEC.KEY=VALUE: a setting of the seed payloads, over the codec's fast test settings "
             "(repeat; KEY=VALUE when one codec is fuzzed).")] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", rich_help_panel=OUTPUT,
        help="Folder for the cases that broke the contract (the first 20 of each codec), as .lwb files.")] = None,
    format: Annotated[str, typer.Option("--format", help="table | md | json", rich_help_panel=OUTPUT)] = "table",
) -> None:
    """Fuzz decoders: mutated payloads (CRC re-sealed) decoded out of process, counted per codec;
    exit status 1 if any case broke the contract (CI can gate on it)."""
    from lwbench.errors import ParameterError
    from lwbench.fuzz import DecodeServer, fuzz_codec

    if format not in ("table", "md", "json"):
        raise ParameterError(f"--format {format!r}: one of table, md, json")
    reg = registry()
    names = list(dict.fromkeys(words(codecs))) or sorted(reg.codecs)
    classes = {name: reg.codec(name) for name in names}  # every name checked before any work
    settings = fuzz_settings(classes, words(param))
    if out is not None:
        writable_folder(out)
    reports, skipped = [], {}
    with progress() as shown, DecodeServer() as server:
        for name, cls in classes.items():
            if cls.needs:  # the oracle: no scan alone makes its payloads (its selection is fuzzed via others')
                skipped[name] = f"cannot run on an arbitrary scan: it needs {cls.needs}"
                continue
            phase = shown.phase(f"fuzzing {name}", cases)
            phase.update(0, what="encoding the seed payloads")
            report = fuzz_codec(cls, settings[name], cases=cases, seconds=seconds, seed=seed, server=server,
                                on_case=lambda done, phase=phase: phase.update(done))
            phase.finish()
            reports.append((name, report))
            if out is not None:
                for i, (verdict, _, case) in enumerate(report.failures):
                    (out / f"{name}-{i}-{verdict.replace(' ', '_')}.lwb").write_bytes(case)
    _print(reports, skipped, settings, format, cases, seed)
    escapes = sum(r.other for _, r in reports)
    for name, r in reports:
        if not r.cases:
            err_console.print(f"[yellow]warning:[/] {escape(name)}: no seed payload could be encoded "
                              "(nothing was fuzzed)", highlight=False)
    if escapes:
        where = ", ".join(f"{n} {r.other}" for n, r in reports if r.other)
        err_console.print(f"[bold red]{escapes} case(s) broke the contract[/] ({escape(where)})"
                          + (f"; written to {escape(str(out))}" if out is not None else ""), highlight=False)
        raise typer.Exit(ESCAPE_STATUS)


def _broke(report) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(report.verdicts.items()) if k != "fine")


def _print(reports, skipped: dict[str, str], settings: dict, format: str, cases: int, seed: int) -> None:
    if format == "json":
        rows = [{"codec": name, "settings": settings[name], "cases": r.cases, "decoded": r.outcomes["ok"],
                 "payload_errors": r.payload_errors, "other": r.other,
                 "broke": {k: v for k, v in sorted(r.verdicts.items()) if k != "fine"},
                 "outcomes": dict(sorted(r.outcomes.items())), "max_cpu_s": r.max_cpu_s,
                 "max_peak_mb": r.max_peak_mb, "seconds": r.seconds,
                 "failures": [{"verdict": v, "message": m, "bytes": len(c)} for v, m, c in r.failures]}
                for name, r in reports]
        rows += [{"codec": name, "skipped": why} for name, why in skipped.items()]
        print(json.dumps(rows, indent=1, default=str))
        return
    if format == "md":
        print("| codec | cases | decoded | PayloadError | other | max CPU s | max peak MB | wall s |")
        print("|---|---|---|---|---|---|---|---|")
        for name, r in reports:
            print(f"| {name} | {r.cases} | {r.outcomes['ok']} | {r.payload_errors} | {r.other} | "
                  f"{r.max_cpu_s:.2f} | {r.max_peak_mb:.0f} | {r.seconds:.0f} |")
        notes = [f"- {name}: {_broke(r)}" for name, r in reports if r.other]
        notes += [f"- {name}: skipped ({why})" for name, why in skipped.items()]
        if notes:
            print("\n" + "\n".join(notes))
        return
    from rich.table import Table

    table = Table(title=f"Fuzzing: {cases} mutated payloads per codec, seed {seed}", title_justify="left")
    for col in ("codec", "cases", "decoded", "PayloadError", "other", "what broke", "max CPU s", "max peak MB",
                "wall s"):
        table.add_column(col, justify="left" if col in ("codec", "what broke") else "right")
    for name, r in reports:
        other = f"[bold red]{r.other}[/]" if r.other else "0"
        table.add_row(escape(name), str(r.cases), str(r.outcomes["ok"]), str(r.payload_errors), other,
                      escape(_broke(r)) or "-", f"{r.max_cpu_s:.2f}", f"{r.max_peak_mb:.0f}", f"{r.seconds:.0f}")
    console.print(table)
    for name, why in skipped.items():
        console.print(f"[dim]{escape(name)} skipped: {escape(why)}[/]")
