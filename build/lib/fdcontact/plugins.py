"""The package's FreeFEM plugins (freefem/plugins/*.cpp), built where they are missing or
older than their sources.

In a checkout `make setup` builds them; an installed package (pip install) ships their
sources and builds them here on first use, into its own freefem/plugins folder, with
FreeFEM's plugin compiler ff-c++ (Debian: libfreefem++-dev, libmumps-seq-dev, g++). What
each plugin links besides FreeFEM is freefem/plugins/link_flags.txt, which the Makefile
reads too. A build runs in a scratch folder and the result is moved in place under a lock,
so two runs starting at once build a plugin once and a running FreeFEM keeps the old file.
"""

import fcntl
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from .errors import FreeFemError
from .paths import FREEFEM_DIR

PLUGIN_DIR = FREEFEM_DIR / "plugins"


def link_flags():
    """{plugin: [flags]} from link_flags.txt (NAME: flags; # comments)."""
    flags = {}
    for line in (PLUGIN_DIR / "link_flags.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, rest = line.partition(":")
            flags[name.strip()] = rest.split()
    return flags


def stale_plugins():
    """The plugins whose .so is missing or older than its source, a header or the flags."""
    shared = [*PLUGIN_DIR.glob("*.hpp"), PLUGIN_DIR / "link_flags.txt"]
    out = []
    for source in sorted(PLUGIN_DIR.glob("*.cpp")):
        built = source.with_suffix(".so")
        newest = max(p.stat().st_mtime for p in [source, *shared])
        if not built.is_file() or built.stat().st_mtime < newest:
            out.append(source.stem)
    return out


def ensure_plugins():
    """Build the stale plugins (nothing to do, the common case, costs a few stat calls)."""
    if not stale_plugins():
        return
    compiler = shutil.which("ff-c++")
    if compiler is None:
        raise FreeFemError(f"the plugins in {PLUGIN_DIR} need building and ff-c++ is missing (Debian packages "
                           f"libfreefem++-dev libmumps-seq-dev g++; in a checkout: make setup)")
    with open(PLUGIN_DIR / ".build-lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        flags = link_flags()
        for name in stale_plugins():        # again under the lock: another run may have built them
            build(compiler, name, flags.get(name, []))


def build(compiler, name, flags):
    with tempfile.TemporaryDirectory(prefix="fdcontact-plugin-") as tmp:
        shutil.copy(PLUGIN_DIR / f"{name}.cpp", tmp)
        proc = subprocess.run([compiler, f"{name}.cpp", f"-I{PLUGIN_DIR}", *flags], cwd=tmp,
                              capture_output=True, text=True)
        built = Path(tmp) / f"{name}.so"
        if proc.returncode != 0 or not built.is_file():
            tail = " ".join((proc.stdout + proc.stderr).strip().splitlines()[-3:])
            raise FreeFemError(f"could not build the plugin {name} (ff-c++ exit {proc.returncode}): {tail}")
        os.replace(shutil.move(str(built), PLUGIN_DIR / f".{name}.so.new"), PLUGIN_DIR / f"{name}.so")
