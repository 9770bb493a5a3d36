"""Where the package's files are: the folder holding freefem/ (FreeFEM's scripts, run from
there) and cases/ is the checkout's root, or the installed package itself (pip install:
package data)."""

from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
REPO = PACKAGE.parent if (PACKAGE.parent / "freefem").is_dir() else PACKAGE
IN_CHECKOUT = REPO != PACKAGE
FREEFEM_DIR = REPO / "freefem"
