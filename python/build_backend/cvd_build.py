"""The package's build backend: maturin's, after deciding whether the
wheel gets the SPIR-V kernels (the Vulkan backend) and checking, in
seconds, that what that build needs is there.

The kernels are built when asked for (`CVD_KERNELS=1` in the environment,
or `pip install ./python -C kernels=yes`), or, when nothing is asked, when
spirv-tools (spirv-val and spirv-opt) are on the PATH; never when told not
to (`CVD_KERNELS=0`, `-C kernels=no`). Without them the package is complete
on the CPU backend and builds minutes faster.

Every hook is maturin's own behind these checks (maturin imported when
called, so that the decision can be tested without it).
"""

import os
import shutil
import sys

_YES = ("1", "yes", "true", "on")
_NO = ("0", "no", "false", "off")


def _stop(message):
    sys.stderr.write(f"\ncvd: {message}\n\n")
    raise SystemExit(1)


def _asked(config_settings):
    """`True`/`False` when the kernels were asked for or refused, else
    `None`; a value neither yes nor no stops the build."""
    for name, value in (
        ("-C kernels", (config_settings or {}).get("kernels")),
        ("CVD_KERNELS", os.environ.get("CVD_KERNELS")),
    ):
        if value is None or value == "":
            continue
        v = str(value).strip().lower()
        if v in _YES:
            return True
        if v in _NO:
            return False
        _stop(f"{name}={value!r}: expected yes or no (1 or 0)")
    return None


def _check(config_settings):
    """Stops, naming the one command to run, where the build cannot work:
    before any hook compiles or downloads anything (maturin would fetch a
    stable Rust that this workspace's pinned nightly does not use).
    Returns whether the kernels are asked for (`None`: not said) and the
    spirv-tools missing."""
    asked = _asked(config_settings)
    if shutil.which("cargo") is None:
        _stop(
            "building the package needs Rust (cargo), which is not on the PATH: install rustup with "
            "`curl --proto '=https' -sSf https://sh.rustup.rs | sh` (or your system's rustup package), "
            "then run pip again"
        )
    tools = [t for t in ("spirv-val", "spirv-opt") if shutil.which(t) is None]
    kernels = asked if asked is not None else not tools
    if kernels and tools:
        _stop(
            f"the SPIR-V kernels were asked for but {' and '.join(tools)} (spirv-tools) "
            "cannot be found: run `sudo xtask/install-deps build` from the repository (or install "
            "spirv-tools), or build without them (CVD_KERNELS=0: the CPU backend)"
        )
    return asked, tools


def _configure(config_settings):
    """Checks the tools and sets maturin's arguments; says in one line what
    it builds and how to get the other build."""
    asked, tools = _check(config_settings)
    kernels = asked if asked is not None else not tools
    settings = dict(config_settings or {})
    settings.pop("kernels", None)
    if kernels:
        # maturin takes its arguments from the settings' build-args when
        # given, else from MATURIN_PEP517_ARGS.
        key = next((k for k in ("maturin.build-args", "build-args") if k in settings), None)
        if key is not None:
            given = settings[key]
            settings[key] = ([*given, "--features", "vulkan"] if isinstance(given, list) else f"{given} --features vulkan")
        else:
            os.environ["MATURIN_PEP517_ARGS"] = f"{os.environ.get('MATURIN_PEP517_ARGS', '')} --features vulkan".strip()
        how = "with the SPIR-V kernels (CPU and Vulkan backends); CVD_KERNELS=0 builds without them, minutes faster"
    else:
        why = "not asked for" if asked is False else "spirv-tools not found"
        how = (
            f"without the SPIR-V kernels ({why}): the CPU backend only; for Vulkan too, "
            "CVD_KERNELS=1 with spirv-tools installed (`sudo xtask/install-deps build`)"
        )
    sys.stderr.write(f"cvd: building {how}\n")
    return settings or None


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    import maturin

    return maturin.build_wheel(wheel_directory, _configure(config_settings), metadata_directory)


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    import maturin

    return maturin.build_editable(wheel_directory, _configure(config_settings), metadata_directory)


def get_requires_for_build_wheel(config_settings=None):
    _check(config_settings)
    import maturin

    return maturin.get_requires_for_build_wheel(config_settings)


def get_requires_for_build_editable(config_settings=None):
    _check(config_settings)
    import maturin

    return maturin.get_requires_for_build_editable(config_settings)


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    _check(config_settings)
    import maturin

    return maturin.prepare_metadata_for_build_wheel(metadata_directory, config_settings)


def prepare_metadata_for_build_editable(metadata_directory, config_settings=None):
    _check(config_settings)
    import maturin

    return maturin.prepare_metadata_for_build_editable(metadata_directory, config_settings)


def get_requires_for_build_sdist(config_settings=None):
    import maturin

    return maturin.get_requires_for_build_sdist(config_settings)


def build_sdist(sdist_directory, config_settings=None):
    import maturin

    return maturin.build_sdist(sdist_directory, config_settings)
