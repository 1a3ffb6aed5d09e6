"""``transcalib show DIR``: print a saved calibration (``calibration.json`` + ``arrays.npz``)."""

from __future__ import annotations

from .common import add_output_options, print_json

NAME = "show"
HELP = "print a saved calibration (the --out folder of calibrate)"


def add_parser(sub) -> None:
    s = sub.add_parser(NAME, help=HELP, description=HELP)
    g = s.groups()
    g["inputs"].add_argument("folder", metavar="DIR", help="folder with calibration.json, or the .json file")
    add_output_options(g["outputs"], folder=False, quiet=False)
    s.set_defaults(func=run)


def run(args) -> int:
    from ..io.calibration_file import load_saved
    from .summary import summary_json, summary_text

    saved = load_saved(args.folder)
    cal = saved.calibration
    unit = saved.document.get("unit") or "units"
    if args.json:
        out = summary_json(cal, unit)
        out.update(status="ok", exit_code=0, schema_version=saved.document["schema_version"],
                   software=saved.document["software"], inputs=saved.inputs)
        print_json(out)
    else:
        print(summary_text(cal, unit))
        soft = saved.document["software"]
        print(f"\n(saved by {soft['name']} {soft['version']}, schema {saved.document['schema_version']}; "
              f"inputs: {saved.inputs.get('tracks') or 'images'}, {saved.inputs.get('poses')})")
    return 0
