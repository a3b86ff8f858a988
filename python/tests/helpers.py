"""What the tests share: whether they run under CI, the tools they import
(a skip with the reason where absent, a failure under CI=true), and the
`cvd` command line built beside the package."""

import os
import shutil

import pytest

CI = os.environ.get("CI") == "true"


def need(module):
    """`module`, or a skip with the reason (a failure under CI=true)."""
    try:
        return __import__(module)
    except ImportError:
        if CI:
            pytest.fail(f"CI=true but {module} is not installed (python3 -m pip install {module})")
        pytest.skip(f"{module} is not installed")


def cli_path():
    """The `cvd` command line built beside this package (CVD_BIN), or None."""
    path = os.environ.get("CVD_BIN") or shutil.which("cvd")
    return path if path and os.path.exists(path) else None


def cli():
    """The `cvd` command line, or a skip (a failure under CI=true)."""
    path = cli_path()
    if path is None:
        if CI:
            pytest.fail("CI=true but the cvd command line is not built (CVD_BIN)")
        pytest.skip("the cvd command line is not built (set CVD_BIN)")
    return path
