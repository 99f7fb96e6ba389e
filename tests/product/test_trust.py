"""What mcjax loads as code from its caches: the program store's pickled programs and the native
kernels' shared library are loaded only when the file is this user's alone and unaltered since
it was written. Each case plants a file that would create a marker file when loaded (a pickle
whose unpickling opens a file; a library whose constructor does) and checks the marker is not
there; the same file, planted as a trusted one, does create it (so the checks can fail)."""

from __future__ import annotations

import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import pytest

from mcjax import runtime
from mcjax.tracking.filters import native


class Payload:
    """Unpickling it opens (creates) ``marker``: code run by loading the file."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return open, (str(self.marker), "w")


@pytest.fixture
def store(tmp_path, monkeypatch):
    monkeypatch.setenv("MCJAX_CACHE_DIR", str(tmp_path / "cache"))
    runtime._WARNED.clear()
    return tmp_path


def _plant(key: str, blob: bytes, name_blob: bytes | None = None) -> Path:
    folder, prefix = runtime._executable_stem(key)
    path = runtime.private_folder(folder) / runtime.content_name(prefix, blob if name_blob is None else name_blob,
                                                                 ".pkl")
    return runtime.write_private(path, blob)


def _load(key: str):
    return runtime.load_executable(key, jax.devices("cpu")[0])


def test_a_trusted_file_is_unpickled_so_the_payload_would_run(store):
    marker = store / "ran"
    _plant("control", pickle.dumps(Payload(marker)))
    assert _load("control") is None  # not a program: then compiled afresh
    assert marker.exists()


@pytest.mark.parametrize("case", ["group_writable", "other_writable", "altered", "wrong_name", "other_owner",
                                  "symlink"])
def test_an_untrusted_store_file_is_not_unpickled(store, case, capsys):
    if case == "other_owner" and os.getuid() != 0:
        pytest.skip("giving a file to another user needs root")
    marker = store / "ran"
    blob = pickle.dumps(Payload(marker))
    path = _plant(case, blob)
    if case == "group_writable":
        os.chmod(path, 0o620)
    elif case == "other_writable":
        os.chmod(path, 0o602)
    elif case == "altered":
        path.write_bytes(blob.replace(b"ran", b"RAN"))
    elif case == "wrong_name":
        path.rename(path.with_name(path.name[:-10] + "0" * 6 + ".pkl"))
    elif case == "other_owner":
        os.chown(path, 65534, 65534)
    elif case == "symlink":
        target = store / "elsewhere.pkl"
        path.rename(target)
        path.symlink_to(target)
    assert _load(case) is None
    assert not marker.exists() and not (store / "RAN").exists()
    err = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(err) == 1 and err[0].startswith("warning: not loading the stored program ") and path.name[:20] in err[0]


def test_a_folder_others_may_write_is_not_trusted(store, capsys):
    marker = store / "ran"
    path = _plant("shared", pickle.dumps(Payload(marker)))
    os.chmod(path.parent, 0o777)
    assert _load("shared") is None and not marker.exists()
    assert "may be written by another user" in capsys.readouterr().err


def test_the_store_writes_its_folder_0700_and_files_0600_named_by_their_hash(store):
    folder, prefix = runtime._executable_stem("modes")
    folder.mkdir(parents=True, mode=0o755)
    os.chmod(folder, 0o755)  # as an older mcjax left it
    runtime.store_executable("modes", (b"blob", None, None), frozenset())
    (path,) = folder.glob(f"{prefix}-*.pkl")
    assert oct(folder.stat().st_mode & 0o777) == "0o700" and oct(path.stat().st_mode & 0o777) == "0o600"
    data, why = runtime.trusted_read(path)
    assert why == "" and data == path.read_bytes()


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
@pytest.mark.parametrize("case", ["trusted", "group_writable", "altered"])
def test_the_native_library_is_loaded_only_when_trusted(tmp_path, case, capsys):
    marker = tmp_path / "ran"
    source = tmp_path / "evil.c"
    source.write_text('#include <stdio.h>\n__attribute__((constructor)) static void run(void) '
                      f'{{ FILE *f = fopen("{marker}", "w"); if (f) fclose(f); }}\n')
    built = tmp_path / "evil.so"
    subprocess.run(["cc", "-shared", "-fPIC", str(source), "-o", str(built)], check=True, capture_output=True)
    folder = runtime.private_folder(tmp_path / "native")
    data = built.read_bytes()
    path = runtime.write_private(folder / runtime.content_name(f"filters-{case}", data, ".so"), data)
    if case == "group_writable":
        os.chmod(path, 0o660)
    elif case == "altered":
        path.write_bytes(data + b"\0")
    runtime._WARNED.clear()
    lib = native.load_library(folder, f"filters-{case}")
    assert (lib is not None) == marker.exists() == (case == "trusted")
    if case != "trusted":
        assert "warning: not loading the native kernels' library" in capsys.readouterr().err


def test_the_native_kernels_build_into_a_private_folder(tmp_path):
    code = ("from mcjax.tracking.filters import native; ok = native.available(); print(ok, native.STATUS['reason'])")
    env = {**os.environ, "MCJAX_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    if not out.stdout.startswith("True"):
        pytest.skip(f"native kernels unavailable here: {out.stdout.strip()} {out.stderr.strip()[-200:]}")
    folder = tmp_path / "cache" / "mcjax-native"
    (lib,) = folder.glob("filters-*.so")
    assert oct(folder.stat().st_mode & 0o777) == "0o700" and oct(lib.stat().st_mode & 0o777) == "0o600"
    assert runtime.trusted_read(lib)[1] == ""


def test_where_a_scenario_came_from_is_told(tmp_path, monkeypatch):
    """A file or module scenario is named with its origin (mcjax sweep / run / tune print it);
    a built-in one is not."""
    import dataclasses

    from mcjax import scenarios

    (tmp_path / "trust_probe_module.py").write_text(
        "import dataclasses\nfrom mcjax.scenarios import sun2011\n"
        "SCENARIO = dataclasses.replace(sun2011.SCENARIO, name='copy')\n")
    (tmp_path / "probe_file.py").write_text((tmp_path / "trust_probe_module.py").read_text())
    monkeypatch.syspath_prepend(str(tmp_path))
    by_module = scenarios.get("trust_probe_module:SCENARIO")
    by_file = scenarios.get("probe_file.py:SCENARIO", base_dir=tmp_path)
    assert scenarios.describe(by_module) == (f"copy (imported from module trust_probe_module "
                                             f"({tmp_path / 'trust_probe_module.py'}))")
    assert scenarios.describe(by_file) == f"copy (imported from {tmp_path / 'probe_file.py'})"
    builtin = scenarios.get("leader_follower")
    assert scenarios.describe(builtin) == "leader_follower" and scenarios.origin(builtin) is None
    assert scenarios.origin(dataclasses.replace(builtin, name="other")) is None  # not imported by get
