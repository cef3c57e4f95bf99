"""Installs the Python tools (tools/: the cdro-tools package) for `cmake --install`, offline.

A virtual environment at VENV (--system-site-packages: Debian's python3-numpy, python3-scipy,
... provide the dependencies; nothing is downloaded), the package's modules and data in its
site-packages with their byte code, the .dist-info that importlib.metadata reads the version
from, a script per console entry point in VENV/bin and a relative symlink to each in BINDIR.

The package is copied, not built: its pyproject.toml needs setuptools >= 77 (PEP 639 licence
metadata) and Debian 12 has 66, so pip could only build it with a download. What a wheel
would hold is written here from the same pyproject.toml.

VENV and BINDIR are the final, absolute paths; with --destdir the files go under that staging
root, and every path written into a file (the scripts' #!, the activate scripts, pyvenv.cfg,
the byte code's source paths) is the final one. The files written are listed, one per line, in
--manifest by their final paths, as CMake's install_manifest.txt lists its own.
"""
from __future__ import annotations

import argparse
import base64
import compileall
import fnmatch
import hashlib
import os
import pathlib
import re
import shutil
import sys
import tomllib
import venv
from importlib import metadata

SCRIPT = '''#!{python}
import sys

try:
    from {module} import {function}
except ModuleNotFoundError as error:
    if error.name is None or error.name.partition(".")[0] == "{package}":
        raise
    sys.exit("{name}: the Python module '" + error.name + "' is not installed. "
             "{lacking}")

if __name__ == "__main__":
    sys.exit({function}())
'''


def staged(destdir: str, path: pathlib.Path) -> pathlib.Path:
    return pathlib.Path(destdir + str(path)) if destdir else path


def version_tuple(text: str) -> tuple[int, ...]:
    return tuple(int(part) for part in re.findall(r"\d+", text.split("+")[0])[:3])


def lacking_requirements(requirements: list[str]) -> list[str]:
    """The requirements this interpreter does not satisfy, each with what it has instead.
    The package only asks for lower bounds (name>=version)."""
    lacking = []
    for requirement in requirements:
        match = re.fullmatch(r"\s*([A-Za-z0-9_.-]+)\s*(?:>=\s*([0-9.]+))?\s*", requirement)
        if match is None:
            raise SystemExit(f"cdro_install_tools: cannot read the requirement '{requirement}'")
        name, minimum = match.groups()
        try:
            have = metadata.version(name)
        except metadata.PackageNotFoundError:
            lacking.append(f"{requirement} (missing)")
            continue
        if minimum and version_tuple(have) < version_tuple(minimum):
            lacking.append(f"{requirement} ({have} installed)")
    return lacking


def package_files(source: pathlib.Path, package_data: dict[str, list[str]]) -> list[pathlib.Path]:
    """What setuptools puts in the wheel: the package's modules and the declared data files."""
    files = []
    for path in sorted(source.rglob("*")):
        if not path.is_file() or "__pycache__" in path.parts:
            continue
        relative = path.relative_to(source).as_posix()
        data = package_data.get(source.name, [])
        if path.suffix == ".py" or any(fnmatch.fnmatch(relative, pattern) for pattern in data):
            files.append(path)
    return files


def create_environment(venv_dir: pathlib.Path, final_venv: pathlib.Path) -> None:
    # An existing environment is kept (clear=False): what an administrator added to it with pip
    # (the dependencies Debian does not package) survives a reinstall.
    venv.EnvBuilder(system_site_packages=True, with_pip=False, symlinks=True, clear=False).create(venv_dir)
    if venv_dir != final_venv:
        for path in [venv_dir / "pyvenv.cfg", *sorted((venv_dir / "bin").glob("[aA]ctivate*"))]:
            path.write_text(path.read_text().replace(str(venv_dir), str(final_venv)))


def record_line(path: pathlib.Path, site: pathlib.Path) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(path.read_bytes()).digest()).rstrip(b"=").decode()
    return f"{pathlib.Path(os.path.relpath(path, site)).as_posix()},sha256={digest},{path.stat().st_size}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", type=pathlib.Path, required=True, help="tools/ (pyproject.toml, cdro_tools)")
    parser.add_argument("--venv", type=pathlib.Path, required=True, help="the environment's final absolute path")
    parser.add_argument("--bindir", type=pathlib.Path, required=True, help="where the commands' links go (final)")
    parser.add_argument("--destdir", default="", help="staging root ($DESTDIR)")
    parser.add_argument("--manifest", type=pathlib.Path, required=True, help="the files written, one a line")
    args = parser.parse_args()
    if not args.venv.is_absolute() or not args.bindir.is_absolute():
        parser.error("--venv and --bindir must be absolute")

    project_toml = tomllib.loads((args.source / "pyproject.toml").read_text())
    project = project_toml["project"]
    package_data = project_toml.get("tool", {}).get("setuptools", {}).get("package-data", {})
    name, version = project["name"], project["version"]
    dist_name = re.sub(r"[-_.]+", "_", name)
    # include = ["cdro_tools*"]: the package and its sub-packages, which are directories of it
    packages = sorted({p.rstrip("*.") for p in project_toml["tool"]["setuptools"]["packages"]["find"]["include"]})
    venv_dir = staged(args.destdir, args.venv)
    bindir = staged(args.destdir, args.bindir)
    site_relative = pathlib.Path("lib", f"python{sys.version_info.major}.{sys.version_info.minor}", "site-packages")
    site, final_site = venv_dir / site_relative, args.venv / site_relative

    create_environment(venv_dir, args.venv)
    for old in [*site.glob(f"{dist_name}-*.dist-info"), *(site / p for p in packages)]:
        if old.is_dir():
            shutil.rmtree(old)

    written: list[pathlib.Path] = []
    for package in packages:
        for path in package_files(args.source / package, package_data):
            target = site / package / path.relative_to(args.source / package)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, target)
            written.append(target)
        # Byte code now, naming the final paths: the users who run the tools cannot write it there.
        if not compileall.compile_dir(str(site / package), ddir=str(final_site / package), quiet=1):
            raise SystemExit(f"cdro_install_tools: byte-compiling {package} failed")
        written.extend(sorted((site / package).rglob("*.pyc")))

    lacking = lacking_requirements(project.get("dependencies", []))
    if lacking:
        advice = ("This system's Python lacked, when the tools were installed: " + ", ".join(lacking) +
                  f". Add them to the tools' environment: {args.venv}/bin/python -m pip install " +
                  " ".join(f"'{r.split(' (')[0]}'" for r in lacking) + " (docs/deployment.md)")
    else:
        advice = "The tools' dependencies are in docs/deployment.md."
    scripts = {}
    for script, target in project.get("scripts", {}).items():
        module, function = target.split(":")
        path = venv_dir / "bin" / script
        path.write_text(SCRIPT.format(python=args.venv / "bin" / "python", module=module, function=function,
                                      package=module.partition(".")[0], name=script,
                                      lacking=advice.replace("\\", "\\\\").replace('"', '\\"')))
        path.chmod(0o755)
        scripts[script] = path
        written.append(path)

    dist_info = site / f"{dist_name}-{version}.dist-info"
    dist_info.mkdir()
    meta = ["Metadata-Version: 2.1", f"Name: {name}", f"Version: {version}"]
    if "description" in project:
        meta.append(f"Summary: {project['description']}")
    if "requires-python" in project:
        meta.append(f"Requires-Python: {project['requires-python']}")
    meta += [f"Requires-Dist: {r}" for r in project.get("dependencies", [])]
    (dist_info / "METADATA").write_text("\n".join(meta) + "\n")
    (dist_info / "INSTALLER").write_text("cdro-slam cmake --install\n")
    (dist_info / "top_level.txt").write_text("".join(p + "\n" for p in packages))
    (dist_info / "entry_points.txt").write_text(
        "[console_scripts]\n" + "".join(f"{s} = {t}\n" for s, t in project.get("scripts", {}).items()))
    record = dist_info / "RECORD"
    lines = [record_line(p, site) for p in sorted([*written, *dist_info.iterdir()])]
    record.write_text("\n".join([*lines, f"{record.relative_to(site).as_posix()},,"]) + "\n")
    written.extend([*dist_info.iterdir()])

    bindir.mkdir(parents=True, exist_ok=True)
    for script in scripts:
        link = bindir / script
        if link.is_symlink() or link.exists():
            link.unlink()
        link.symlink_to(os.path.relpath(args.venv / "bin" / script, args.bindir))
        written.append(link)

    # What venv itself made (not what pip may have added since)
    venv_files = [venv_dir / "pyvenv.cfg", *(venv_dir / "bin").glob("python*"), *(venv_dir / "bin").glob("[aA]ctivate*")]
    venv_files += [p for p in [venv_dir / "lib64"] if p.is_symlink()]
    manifest = sorted({str(p)[len(args.destdir):] for p in [*written, *venv_files]})
    args.manifest.write_text("".join(line + "\n" for line in manifest))
    if lacking:
        print("cdro-tools: this system's Python lacks " + ", ".join(lacking) + "; the tools that import them "
              f"fail until they are added: {args.venv}/bin/python -m pip install ... (docs/deployment.md)",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
