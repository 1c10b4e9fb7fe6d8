"""Foxglove's own protobuf schemas (foxglove-schemas-protobuf), as an MCAP schema record holds them."""

from __future__ import annotations

from typing import Any


def descriptor_set(desc: Any) -> bytes:
    """The FileDescriptorSet of message descriptor `desc` with every file it depends on, dependencies first."""
    from google.protobuf import descriptor_pb2

    files: dict = {}

    def add(fd: Any) -> None:
        for dep in fd.dependencies:
            add(dep)
        if fd.name not in files:
            files[fd.name] = descriptor_pb2.FileDescriptorProto()
            fd.CopyToProto(files[fd.name])

    add(desc.file)
    return descriptor_pb2.FileDescriptorSet(file=list(files.values())).SerializeToString()
