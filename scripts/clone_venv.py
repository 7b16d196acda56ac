"""This clone's ``.venv``: a thin venv over the cached, shared one that always runs this clone's source.

    BASE/bin/python scripts/clone_venv.py LAYER SRC       (what scripts/bootstrap.sh runs)

Several clones share one cached venv (``~/.cache/simseam/venvs/``, keyed by the pins). An editable install
in it can point at one clone only, so no clone relies on it: each clone's ``LAYER`` (``.venv``) is a venv
of its own without pip (``python -m venv --without-pip``, made in well under a second) whose
site-packages holds one ``.pth`` that puts ``SRC`` (this clone's ``src/``) on ``sys.path`` first and then
adds BASE's site-packages (``site.addsitedir``, so BASE's own ``.pth`` files are read after it). Its
``bin/`` holds ``simseam`` and BASE's other console scripts, started by the layer's interpreter.
``LAYER/bin/python``, ``LAYER/bin/simseam`` and every process they start with ``sys.executable``
(sidecars, worker processes, Ray workers) import this clone's simseam, whatever another clone set up or
ran. ``pip`` run from the layer installs into the layer, never into the shared venv.

The layer's stamp ``simseam-layer`` (``key=value`` lines: base, src, the base's own stamp) is written
last; a second run that finds the same one touches nothing. An older set-up's symlink at ``LAYER`` is
replaced; a directory at ``LAYER`` that is not a layer (a full venv) is never touched (exit 2).
Standard library only: it runs before the layer exists, on BASE's interpreter.
"""

from __future__ import annotations

import os
import shutil
import sys
import sysconfig
import venv
from pathlib import Path

STAMP = "simseam-layer"
PTH = "00-simseam-clone.pth"
SKIP = ("python", "activate", "Activate", "__pycache__")


def stamp_text(base: Path, src: Path) -> str:
    try:
        base_stamp = (base / ".simseam-installed").read_text().strip()
    except OSError:
        base_stamp = ""
    return f"base={base}\nsrc={src}\nbase_stamp={base_stamp}\npython={sys.version.split()[0]}\n"


def site_packages(prefix: Path) -> Path:
    return Path(sysconfig.get_path("purelib", vars={"base": str(prefix), "platbase": str(prefix)}))


def console_scripts(base: Path, layer: Path) -> None:
    """BASE's console scripts, each started by the layer's interpreter; ``simseam`` always."""
    shebang = f"#!{layer / 'bin' / 'python'}\n"
    for entry in sorted((base / "bin").iterdir()):
        if entry.name.startswith(SKIP) or not entry.is_file() or entry.is_symlink():
            continue
        try:
            first, rest = entry.read_text().split("\n", 1)
        except (UnicodeDecodeError, ValueError, OSError):
            continue  # a binary or an empty file: nothing to re-point
        if first.startswith((f"#!{base / 'bin' / 'python'}", f"#!{Path(sys.prefix) / 'bin' / 'python'}")):
            write_script(layer / "bin" / entry.name, shebang + rest)
    write_script(layer / "bin" / "simseam",
                 shebang + "import sys\nfrom simseam.cli.main import app\n\nif __name__ == '__main__':\n"
                           "    sys.exit(app())\n")


def write_script(path: Path, text: str) -> None:
    path.write_text(text)
    path.chmod(0o755)


def make_layer(layer: Path, src: Path) -> bool:
    """Make or refresh ``layer`` over this interpreter's venv (the base); False when it was current."""
    base = Path(sys.prefix).resolve()
    want = stamp_text(base, src)
    if layer.is_symlink():  # the older set-up: .venv was a link to the shared venv itself
        layer.unlink()
    elif layer.is_dir():
        if not (layer / STAMP).is_file():
            raise SystemExit(f"clone_venv: {layer} is a venv of its own, not a layer; left as it is")
        if (layer / STAMP).read_text() == want:
            return False
        shutil.rmtree(layer)
    elif layer.exists():
        raise SystemExit(f"clone_venv: {layer} exists and is not a directory; left as it is")
    venv.EnvBuilder(with_pip=False, symlinks=True).create(layer)
    # SRC first; then the base's packages, and its .pth files (an editable simseam of some clone comes
    # after SRC, so it is never the one imported)
    (site_packages(layer) / PTH).write_text(f"{src}\nimport site; site.addsitedir({str(site_packages(base))!r})\n")
    console_scripts(base, layer)
    (layer / STAMP).write_text(want)  # last: a layer without it is rebuilt
    return True


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    layer, src = Path(os.path.abspath(argv[0])), Path(argv[1]).resolve()
    if not (src / "simseam" / "__init__.py").is_file():
        print(f"clone_venv: {src} holds no simseam package", file=sys.stderr)
        return 2
    if sys.prefix == sys.base_prefix:
        print(f"clone_venv: run it with the cached venv's python, not {sys.executable}", file=sys.stderr)
        return 2
    if make_layer(layer, src):
        print(f"[simseam] {layer}: this clone's venv ({src} first, then {sys.prefix})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
