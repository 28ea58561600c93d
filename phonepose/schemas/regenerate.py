"""Regenerate ``phonepose_pb2.py`` from ``phonepose.proto``.

Run from anywhere:  ``python -m phonepose.schemas.regenerate``  (needs the ``dev`` extra: grpcio-tools).

The Foxglove package ships generated Python but no ``.proto`` sources, so the imported
Foxglove and Google files are handed to protoc as a descriptor set built from the installed
modules; the generated import of ``foxglove`` is then pointed at ``foxglove_schemas_protobuf``.
"""

from __future__ import annotations

import pathlib
import re
import sys
import tempfile

from foxglove_schemas_protobuf import Pose_pb2, Quaternion_pb2, Vector3_pb2
from google.protobuf import descriptor_pb2, timestamp_pb2

HERE = pathlib.Path(__file__).resolve().parent


def _descriptor_set() -> bytes:
    fds = descriptor_pb2.FileDescriptorSet()
    for module in (timestamp_pb2, Vector3_pb2, Quaternion_pb2, Pose_pb2):
        fdp = descriptor_pb2.FileDescriptorProto()
        module.DESCRIPTOR.CopyToProto(fdp)
        fds.file.append(fdp)
    return fds.SerializeToString()


def main() -> int:
    from grpc_tools import protoc

    with tempfile.TemporaryDirectory() as tmp:
        deps = pathlib.Path(tmp) / "deps.pb"
        deps.write_bytes(_descriptor_set())
        rc = protoc.main(
            [
                "protoc",
                f"--descriptor_set_in={deps}",
                f"-I{HERE}",
                f"--python_out={HERE}",
                f"--pyi_out={HERE}",
                str(HERE / "phonepose.proto"),
            ]
        )
    if rc != 0:
        return rc
    for name in ("phonepose_pb2.py", "phonepose_pb2.pyi"):
        path = HERE / name
        text = path.read_text()
        text = re.sub(r"^from foxglove import", "from foxglove_schemas_protobuf import", text, flags=re.M)
        path.write_text(text)
    print(f"regenerated {HERE / 'phonepose_pb2.py'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
