"""`tracklabel labelset ...`: the label sets shipped, one shown class by class, a file checked."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from app.cli_common import friendly_errors

labelset_app = typer.Typer(no_args_is_help=True, help="Label sets: the classes of a project, as YAML.")

NameArg = Annotated[str, typer.Argument(help="A preset (see `labelset list`) or a label set file.")]


@labelset_app.command("list")
def labelset_list() -> None:
    """The presets shipped with tracklabel (the default first) and their class counts."""
    from pipeline.label_sets import preset, preset_names

    for name in preset_names():
        s = preset(name)
        typer.echo(f"{name:<16} {len(s.classes):>3} classes ({len(s.ground_classes)} ground)  {s.description}")


@labelset_app.command("show")
@friendly_errors
def labelset_show(name: NameArg) -> None:
    """Every class of a label set in index order: key, kind, ground, ids written and read, colour."""
    from pipeline.label_sets import load_label_set

    s = load_label_set(name)
    typer.echo(f"{s.name}: {s.description}".rstrip(": "))
    typer.echo(f"{'index':>5}  {'name':<22}{'key':<5}{'kind':<7}{'ground':<8}{'writes/moving':<14}{'colour':<16}reads")
    for i, c in enumerate(s.point_classes):
        writes = f"{c.writes}" + (f"/{c.moving}" if c.moving is not None else "")
        colour = "#{:02x}{:02x}{:02x}".format(*c.colour)
        ground = "yes" if c.ground else ""
        typer.echo(f"{i:>5}  {c.name:<22}{c.key or '-':<5}{c.kind:<7}{ground:<8}{writes:<14}{colour:<16}"
                   f"{', '.join(map(str, c.reads)) or '-'}")
    typer.echo(f"unlabelled ids: {', '.join(map(str, s.unlabelled_ids))}; "
               f"other ids: {s.fallback or 'unlabelled'}")


@labelset_app.command("check")
@friendly_errors
def labelset_check(path: Annotated[Path, typer.Argument(help="A label set YAML file.")]) -> None:
    """Validate a label set file: exit 0 when valid, exit 2 naming the file and the field when not."""
    from pipeline.label_sets import read_label_set

    s = read_label_set(path)
    typer.echo(f"{path}: label set {s.name} is valid: {len(s.classes)} classes "
               f"({len(s.sample_classes)} sample, {len(s.ground_classes)} ground)")


@labelset_app.command("import")
@friendly_errors
def labelset_import(
    path: Annotated[Path, typer.Argument(help="A semantic-kitti.yaml style file (labels, color_map, learning_map).")],
    name: Annotated[str | None, typer.Option(help="The label set's name (default: the file's name).")] = None,
    out: Annotated[Path | None, typer.Option(help="Write the label set here (default: print it).")] = None,
) -> None:
    """Turn a semantic-kitti.yaml style file into a label set file."""
    from pipeline.label_sets import dump_label_set, from_semantickitti_yaml

    text = dump_label_set(from_semantickitti_yaml(path, name=name))
    if out is None:
        typer.echo(text, nl=False)
    else:
        out.write_text(text)
        typer.echo(f"wrote {out}")
