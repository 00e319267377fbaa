"""The committed hercs/proto/hercs_pb2.py must be what `make proto` generates from hercs.proto."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PROTO_DIR = Path(__file__).resolve().parents[3] / "hercs" / "proto"


@pytest.mark.parametrize("generated", ["hercs_pb2.py", "hercs_pb2.pyi"])
def test_committed_module_is_fresh(tmp_path: Path, generated: str) -> None:
    shutil.copy(PROTO_DIR / "hercs.proto", tmp_path / "hercs.proto")
    subprocess.run(
        [sys.executable, "-m", "grpc_tools.protoc", "-I.", "--python_out=.", "--pyi_out=.",
         "hercs.proto"],
        cwd=tmp_path, check=True,
    )
    fresh = (tmp_path / generated).read_text()
    committed = (PROTO_DIR / generated).read_text()
    assert committed == fresh, f"hercs/proto/{generated} is stale: run `make proto` and commit it"
