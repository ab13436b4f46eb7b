"""Point the message wheels' exported CMake include paths at this virtual environment.

The ROS message wheels from PyPI install CMake export files
(``share/<pkg>/cmake/export_<pkg>__rosidl_generator_pyExport.cmake``) that still name the
wheel builder's Python and numpy include folders (``/opt/python/cp311-cp311/...``).
A package that generates Python bindings for messages depending on them then fails with
"includes non-existent path". This rewrites, in ``INTERFACE_INCLUDE_DIRECTORIES`` lines of
those files only, every Python include folder to this interpreter's and every numpy include
folder to the installed numpy's. It is idempotent and also repairs a moved venv; re-run it
after reinstalling a message wheel.

Usage: ``<venv>/bin/python .ci/fix_cmake_exports.py`` (prints what it changed).
"""

from __future__ import annotations

import re
import sys
import sysconfig
from pathlib import Path

#: Export files of the Python bindings of every message package in the prefix.
EXPORT_GLOB = "share/*/cmake/export_*__rosidl_generator_pyExport.cmake"
#: The one line of such a file that carries include folders.
INCLUDE_LINE = re.compile(r'^(\s*INTERFACE_INCLUDE_DIRECTORIES\s+")([^"]*)(".*)$', re.M)
#: A CPython header folder (``.../include/python3.11``).
PYTHON_INCLUDE = re.compile(r"/include/python3\.\d+$")
#: numpy's C header folder (numpy 2: ``numpy/_core/include``; numpy 1: ``numpy/core/include``).
NUMPY_INCLUDE = re.compile(r"/numpy/_?core/include$")


def rewrite_includes(text: str, python_include: str, numpy_include: str) -> str:
    """Return ``text`` with the Python and numpy include folders replaced.

    Parameters
    ----------
    text : str
        Content of one CMake export file.
    python_include, numpy_include : str
        Absolute folders to use instead.

    Returns
    -------
    str
        The new content (equal to ``text`` when nothing needed changing).
    """

    def one_line(match: re.Match) -> str:
        entries = []
        for entry in match.group(2).split(";"):
            if PYTHON_INCLUDE.search(entry):
                entry = python_include
            elif NUMPY_INCLUDE.search(entry):
                entry = numpy_include
            entries.append(entry)
        return match.group(1) + ";".join(entries) + match.group(3)

    return INCLUDE_LINE.sub(one_line, text)


def main() -> int:
    """Rewrite the export files under ``sys.prefix``; return the exit status."""
    import numpy

    python_include = sysconfig.get_paths()["include"]
    numpy_include = numpy.get_include()
    for folder in (python_include, numpy_include):
        if not Path(folder).is_dir():
            print(f"error: include folder {folder} does not exist", file=sys.stderr)
            return 2
    files = sorted(Path(sys.prefix).glob(EXPORT_GLOB))
    changed = 0
    for path in files:
        text = path.read_text()
        new = rewrite_includes(text, python_include, numpy_include)
        if new != text:
            path.write_text(new)
            changed += 1
    if changed:
        print(f"[setup] include paths rewritten in {changed} of {len(files)} CMake export files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
