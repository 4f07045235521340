"""An ONNX model with a free input size, for onnxruntime, without the ``onnx`` package.

Some models declare a fixed input size although their graph has none (YuNet declares 640 x 640; its reshapes flatten
with -1 and its upsampling uses scales), and onnxruntime refuses any other size. :func:`free_input_size` rewrites
only the declared shapes. It reads the model with the few messages of ONNX's schema it changes (``onnx.proto``'s field
numbers), built here with protobuf (a dependency of onnxruntime); every other field of the model is kept as protobuf
keeps fields it does not know, in their order. Importing the ``onnx`` package for this would cost most of a second
in every process that builds a detector (its ``ml_dtypes`` extension).
"""
from __future__ import annotations

from functools import lru_cache

_MESSAGES = {  # message: [(field, number, label, type or message)], as in onnx.proto (proto2)
    "Dimension": [("dim_value", 1, "optional", "int64"), ("dim_param", 2, "optional", "string")],
    "TensorShapeProto": [("dim", 1, "repeated", "Dimension")],
    "TensorType": [("elem_type", 1, "optional", "int32"), ("shape", 2, "optional", "TensorShapeProto")],
    "TypeProto": [("tensor_type", 1, "optional", "TensorType")],
    "ValueInfoProto": [("name", 1, "optional", "string"), ("type", 2, "optional", "TypeProto")],
    "GraphProto": [("input", 11, "repeated", "ValueInfoProto"), ("output", 12, "repeated", "ValueInfoProto")],
    "ModelProto": [("graph", 7, "optional", "GraphProto")],
}


@lru_cache(maxsize=1)
def _model_class():
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fdp = descriptor_pb2.FileDescriptorProto(name="sweepcast_onnx_shapes.proto", package="sweepcast_onnx",
                                             syntax="proto2")
    scalar = {"int64": descriptor_pb2.FieldDescriptorProto.TYPE_INT64,
              "int32": descriptor_pb2.FieldDescriptorProto.TYPE_INT32,
              "string": descriptor_pb2.FieldDescriptorProto.TYPE_STRING}
    label = {"optional": descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL,
             "repeated": descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED}
    for name, fields in _MESSAGES.items():
        message = fdp.message_type.add(name=name)
        for field, number, how, kind in fields:
            f = message.field.add(name=field, number=number, label=label[how])
            if kind in scalar:
                f.type = scalar[kind]
            else:
                f.type = descriptor_pb2.FieldDescriptorProto.TYPE_MESSAGE
                f.type_name = f".sweepcast_onnx.{kind}"
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fdp)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("sweepcast_onnx.ModelProto"))


def free_input_size(model: bytes, free_axes: dict[int, str]) -> bytes:
    """``model`` (an ONNX file's bytes) with the axes ``free_axes`` (axis -> a name) of its first input made symbolic,
    and every fixed axis of its outputs but the first (the batch) too (their lengths follow the input's size).
    Raises ValueError when ``model`` is not an ONNX model with such an input."""
    from google.protobuf.message import DecodeError

    parsed = _model_class()()
    try:
        parsed.ParseFromString(model)
    except DecodeError as exc:
        raise ValueError(f"not an ONNX model ({exc})") from None
    if not parsed.graph.input or len(parsed.graph.input[0].type.tensor_type.shape.dim) <= max(free_axes):
        raise ValueError("the model has no input with those axes")
    dims = parsed.graph.input[0].type.tensor_type.shape.dim
    for axis, name in free_axes.items():
        dims[axis].ClearField("dim_value")
        dims[axis].dim_param = name
    for output in parsed.graph.output:
        for axis, dim in enumerate(output.type.tensor_type.shape.dim):
            if axis > 0 and dim.HasField("dim_value"):
                dim.ClearField("dim_value")
                dim.dim_param = f"{output.name}_{axis}"
    return parsed.SerializeToString()
