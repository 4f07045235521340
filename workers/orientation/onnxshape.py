"""An ONNX model with a free input size, or a grey input, for onnxruntime, without the ``onnx`` package.

Some models declare a fixed input size although their graph has none (YuNet declares 640 x 640; its reshapes flatten
with -1 and its upsampling uses scales), and onnxruntime refuses any other size. :func:`free_input_size` rewrites
only the declared shapes; :func:`grey_input` makes a colour model take one grey channel. They read the model with the
few messages of ONNX's schema they change (``onnx.proto``'s field numbers), built here with protobuf (a dependency of
onnxruntime); every other field of the model is kept as protobuf keeps fields it does not know, in their order.
Importing the ``onnx`` package for this would cost most of a second in every process that builds a detector (its
``ml_dtypes`` extension).
"""
from __future__ import annotations

from functools import lru_cache

_MESSAGES = {  # message: [(field, number, label, type or message)], as in onnx.proto (proto2)
    "Dimension": [("dim_value", 1, "optional", "int64"), ("dim_param", 2, "optional", "string")],
    "TensorShapeProto": [("dim", 1, "repeated", "Dimension")],
    "TensorType": [("elem_type", 1, "optional", "int32"), ("shape", 2, "optional", "TensorShapeProto")],
    "TypeProto": [("tensor_type", 1, "optional", "TensorType")],
    "ValueInfoProto": [("name", 1, "optional", "string"), ("type", 2, "optional", "TypeProto")],
    "AttributeProto": [("name", 1, "optional", "string"), ("i", 3, "optional", "int64")],
    "NodeProto": [("input", 1, "repeated", "string"), ("output", 2, "repeated", "string"),
                  ("op_type", 4, "optional", "string"), ("attribute", 5, "repeated", "AttributeProto")],
    "TensorProto": [("dims", 1, "repeated", "int64"), ("data_type", 2, "optional", "int32"),
                    ("float_data", 4, "repeated", "float"), ("name", 8, "optional", "string"),
                    ("raw_data", 9, "optional", "bytes")],
    "GraphProto": [("node", 1, "repeated", "NodeProto"), ("initializer", 5, "repeated", "TensorProto"),
                   ("input", 11, "repeated", "ValueInfoProto"), ("output", 12, "repeated", "ValueInfoProto")],
    "ModelProto": [("graph", 7, "optional", "GraphProto")],
}


@lru_cache(maxsize=1)
def _model_class():
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fdp = descriptor_pb2.FileDescriptorProto(name="sweepcast_onnx_shapes.proto", package="sweepcast_onnx",
                                             syntax="proto2")
    scalar = {"int64": descriptor_pb2.FieldDescriptorProto.TYPE_INT64,
              "int32": descriptor_pb2.FieldDescriptorProto.TYPE_INT32,
              "string": descriptor_pb2.FieldDescriptorProto.TYPE_STRING,
              "bytes": descriptor_pb2.FieldDescriptorProto.TYPE_BYTES,
              "float": descriptor_pb2.FieldDescriptorProto.TYPE_FLOAT}
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


def _parse(model: bytes):
    from google.protobuf.message import DecodeError

    parsed = _model_class()()
    try:
        parsed.ParseFromString(model)
    except DecodeError as exc:
        raise ValueError(f"not an ONNX model ({exc})") from None
    return parsed


def free_input_size(model: bytes, free_axes: dict[int, str]) -> bytes:
    """``model`` (an ONNX file's bytes) with the axes ``free_axes`` (axis -> a name) of its first input made symbolic,
    and every fixed axis of its outputs but the first (the batch) too (their lengths follow the input's size).
    Raises ValueError when ``model`` is not an ONNX model with such an input."""
    parsed = _parse(model)
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


_FLOAT = 1
"""TensorProto.DataType FLOAT."""


def grey_input(model: bytes) -> bytes:
    """``model`` (an ONNX file's bytes) whose first input is an image (N, C, H, W) read only by convolutions, made to
    take one channel: each such convolution's weights (O, C, k, k) summed over their C input channels. For an image
    whose C channels are equal (a grey photo given as RGB) it computes what ``model`` computes (to float rounding), on
    1/C of the input and with a first layer that costs 1/C as much. Raises ValueError when ``model`` is not such a
    model (another operation reads the input, a grouped convolution, weights not in float32)."""
    import numpy as np

    parsed = _parse(model)
    graph = parsed.graph
    if not graph.input or len(graph.input[0].type.tensor_type.shape.dim) != 4:
        raise ValueError("the model has no image input (N, C, H, W)")
    name = graph.input[0].name
    readers = [node for node in graph.node if name in node.input]
    weights = {tensor.name: tensor for tensor in graph.initializer}
    if not readers or any(_not_plain_conv(node, name, weights) for node in readers):
        raise ValueError("the model's input is not read by ungrouped float convolutions only")
    for tensor in {node.input[1]: weights[node.input[1]] for node in readers}.values():
        array = (np.frombuffer(tensor.raw_data, dtype="<f4") if tensor.raw_data
                 else np.asarray(tensor.float_data, dtype=np.float32)).reshape(tuple(tensor.dims))
        summed = array.sum(axis=1, keepdims=True, dtype=np.float32)
        tensor.ClearField("float_data")
        tensor.raw_data = summed.astype("<f4").tobytes()
        tensor.dims[:] = summed.shape
    channels = graph.input[0].type.tensor_type.shape.dim[1]
    channels.ClearField("dim_param")
    channels.dim_value = 1
    return parsed.SerializeToString()


def _not_plain_conv(node, name: str, weights: dict) -> bool:
    """Whether ``node`` is anything but an ungrouped float convolution reading ``name`` as its data (input 0) only."""
    group = next((a.i for a in node.attribute if a.name == "group"), 1)
    return (node.op_type != "Conv" or list(node.input).count(name) != 1 or node.input[0] != name or group != 1
            or len(node.input) < 2 or node.input[1] not in weights or weights[node.input[1]].data_type != _FLOAT)
