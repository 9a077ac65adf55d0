#!/usr/bin/env python3
"""Converts MediaPipe's selfie segmentation TFLite models to ONNX (opset 17) with the Python
standard library only: a minimal FlatBuffers reader for the TFLite schema and a minimal protobuf
writer for ONNX. It knows exactly the ops those models use (fp16 weights behind DEQUANTIZE, CONV_2D,
DEPTHWISE_CONV_2D, ADD, MUL, RELU, HARD_SWISH, LOGISTIC, AVERAGE_POOL_2D, MEAN, RESIZE_BILINEAR and
MediaPipe's custom Convolution2DTransposeBias) and refuses any other op or option by name.
The ONNX graph runs NCHW between one input Transpose and one output Transpose; its interface stays
NHWC: input `input` (1xHxWx3 float RGB in [0, 1]), output `mask` (1xHxWx1 person probability).
The output is deterministic (same input bytes, same output bytes).
Usage: scripts/tflite-onnx.py MODEL.tflite OUT.onnx"""
import struct
import sys

# ---- TFLite (FlatBuffers) reading -------------------------------------------------------------


class Table:
    """A FlatBuffers table at byte offset `pos` of `buf`."""

    def __init__(self, buf, pos):
        self.buf, self.pos = buf, pos
        self.vt = pos - struct.unpack_from("<i", buf, pos)[0]
        self.vt_len = struct.unpack_from("<H", buf, self.vt)[0]

    def _field(self, i):
        o = 4 + 2 * i
        return struct.unpack_from("<H", self.buf, self.vt + o)[0] if o < self.vt_len else 0

    def scalar(self, i, fmt, default=0):
        o = self._field(i)
        return struct.unpack_from("<" + fmt, self.buf, self.pos + o)[0] if o else default

    def _indirect(self, i):
        o = self._field(i)
        if not o:
            return None
        p = self.pos + o
        return p + struct.unpack_from("<I", self.buf, p)[0]

    def table(self, i):
        p = self._indirect(i)
        return Table(self.buf, p) if p is not None else None

    def _vector(self, i):
        p = self._indirect(i)
        if p is None:
            return 0, 0
        return p + 4, struct.unpack_from("<I", self.buf, p)[0]

    def tables(self, i):
        start, n = self._vector(i)
        return [Table(self.buf, start + 4 * k + struct.unpack_from("<I", self.buf, start + 4 * k)[0])
                for k in range(n)]

    def ints(self, i):
        start, n = self._vector(i)
        return list(struct.unpack_from("<%di" % n, self.buf, start))

    def bytes(self, i):
        start, n = self._vector(i)
        return self.buf[start:start + n]

    def string(self, i):
        return self.bytes(i).decode()


# TFLite schema: builtin operator codes, tensor types, option enums.
ADD, AVERAGE_POOL_2D, CONV_2D, DEPTHWISE_CONV_2D, DEQUANTIZE = 0, 1, 3, 4, 6
LOGISTIC, MUL, RELU, RESIZE_BILINEAR, CUSTOM, MEAN, HARD_SWISH = 14, 18, 19, 23, 32, 40, 117
FLOAT32, FLOAT16, INT32 = 0, 1, 2
PADDING = {0: "SAME", 1: "VALID"}  # the custom op's TfLitePadding: 1 SAME, 2 VALID

# ---- ONNX (protobuf) writing ------------------------------------------------------------------


def varint(v):
    out = bytearray()
    v &= (1 << 64) - 1
    while True:
        b, v = v & 0x7F, v >> 7
        if not v:
            out.append(b)
            return bytes(out)
        out.append(b | 0x80)


def pint(field, v):
    return varint(field << 3) + varint(v)


def pbytes(field, b):
    if isinstance(b, str):
        b = b.encode()
    return varint(field << 3 | 2) + varint(len(b)) + b


def attribute(name, v):
    if isinstance(v, list):
        return pbytes(1, name) + b"".join(pint(8, x) for x in v) + pint(20, 7)  # INTS
    if isinstance(v, str):
        return pbytes(1, name) + pbytes(4, v) + pint(20, 3)  # STRING
    return pbytes(1, name) + pint(3, v) + pint(20, 2)  # INT


def node(op, inputs, outputs, **attrs):
    return (b"".join(pbytes(1, i) for i in inputs) + b"".join(pbytes(2, o) for o in outputs)
            + pbytes(4, op) + b"".join(pbytes(5, attribute(k, attrs[k])) for k in sorted(attrs)))


def tensor(name, dims, values, fmt):
    data_type = {"f": 1, "q": 7}[fmt]  # FLOAT, INT64
    return (b"".join(pint(1, d) for d in dims) + pint(2, data_type) + pbytes(8, name)
            + pbytes(9, struct.pack("<%d%s" % (len(values), fmt), *values)))


def value_info(name, dims):
    shape = b"".join(pbytes(1, pint(1, d)) for d in dims)
    return pbytes(1, name) + pbytes(2, pbytes(1, pint(1, 1) + pbytes(2, shape)))


# ---- Conversion -------------------------------------------------------------------------------


def transpose(values, dims, perm):
    """Reorders a row-major array of shape `dims` by `perm`; returns (values, new dims)."""
    strides = [1] * len(dims)
    for k in range(len(dims) - 2, -1, -1):
        strides[k] = strides[k + 1] * dims[k + 1]
    new_dims = [dims[p] for p in perm]
    idx = [0]
    for p in perm:
        idx = [i + strides[p] * j for i in idx for j in range(dims[p])]
    return [values[i] for i in idx], new_dims


def same_pads(size, kernel, stride, dilation=1):
    """TensorFlow's SAME padding of one axis: (before, after)."""
    out = -(-size // stride)
    total = max((out - 1) * stride + (kernel - 1) * dilation + 1 - size, 0)
    return total // 2, total - total // 2


class Converter:
    def __init__(self, buf):
        model = Table(buf, struct.unpack_from("<I", buf, 0)[0])
        self.buffers = [b.bytes(0) for b in model.tables(4)]
        self.codes = [(max(c.scalar(0, "b"), c.scalar(3, "i")), c.string(1))
                      for c in model.tables(1)]
        graphs = model.tables(2)
        if len(graphs) != 1:
            sys.exit("tflite-onnx: %d subgraphs, expected 1" % len(graphs))
        self.graph = graphs[0]
        self.tensors = self.graph.tables(0)
        self.consts = {}  # tensor index -> (dims, float or int values)
        self.nodes, self.inits = [], []

    def shape(self, t):
        return self.tensors[t].ints(0)

    def const(self, t):
        """A constant tensor's (dims, values): its buffer, or a folded DEQUANTIZE output."""
        if t in self.consts:
            return self.consts[t]
        tensor_ = self.tensors[t]
        data, kind = self.buffers[tensor_.scalar(2, "I")], tensor_.scalar(1, "b")
        fmt = {FLOAT32: "f", FLOAT16: "e", INT32: "i"}.get(kind)
        if not data or fmt is None:
            sys.exit("tflite-onnx: tensor %d (%s) is not a constant" % (t, tensor_.string(3)))
        return self.shape(t), list(struct.unpack("<%d%s" % (len(data) // struct.calcsize(fmt), fmt), data))

    def init(self, dims, values, fmt="f"):
        name = "c_%d" % (len(self.inits) + 1)
        self.inits.append(tensor(name, dims, values, fmt))
        return name

    def weights(self, t, perm):
        dims, values = self.const(t)
        values, dims = transpose(values, dims, perm)
        return self.init(dims, values)

    def add(self, op, inputs, out, activation=0, **attrs):
        """Adds node `op` writing tensor `out`, followed by its fused activation (none or RELU)."""
        if activation not in (0, 1):
            sys.exit("tflite-onnx: fused activation %d is not supported" % activation)
        name = "t%d" % out if isinstance(out, int) else out
        self.nodes.append(node(op, inputs, [name + "_pre" if activation else name], **attrs))
        if activation:
            self.nodes.append(node("Relu", [name + "_pre"], [name]))

    def conv(self, op, ins, out, depthwise):
        o = op.table(4)
        stride_w, stride_h = o.scalar(1, "i"), o.scalar(2, "i")
        act, dil = (o.scalar(4, "b"), (o.scalar(6, "i", 1), o.scalar(5, "i", 1))) if depthwise else \
            (o.scalar(3, "b"), (o.scalar(5, "i", 1), o.scalar(4, "i", 1)))
        _, h, w, c = self.shape(ins[0])
        kdims = self.const(ins[1])[0]
        pads = [0, 0, 0, 0]
        if PADDING[o.scalar(0, "b")] == "SAME":
            (t, b), (l, r) = (same_pads(h, kdims[1], stride_h, dil[0]),
                              same_pads(w, kdims[2], stride_w, dil[1]))
            pads = [t, l, b, r]
        perm = [3, 0, 1, 2] if depthwise else [0, 3, 1, 2]
        inputs = ["t%d" % ins[0], self.weights(ins[1], perm)]
        if len(ins) > 2 and ins[2] >= 0:
            inputs.append(self.init(*self.const(ins[2])))
        self.add("Conv", inputs, out, act, dilations=list(dil),
                 group=c if depthwise else 1, kernel_shape=kdims[1:3], pads=pads,
                 strides=[stride_h, stride_w])

    def transpose_conv_bias(self, op, ins, out):
        padding, stride_w, stride_h = struct.unpack("<3i", op.bytes(5))
        _, h, w, _ = self.shape(ins[0])
        _, oh, ow, _ = self.shape(out)
        kdims = self.const(ins[1])[0]
        pads = [0, 0, 0, 0]
        if padding == 1:  # SAME: what the output size leaves over, the smaller half first
            th, tw = (h - 1) * stride_h + kdims[1] - oh, (w - 1) * stride_w + kdims[2] - ow
            pads = [th // 2, tw // 2, th - th // 2, tw - tw // 2]
        elif padding != 2:
            sys.exit("tflite-onnx: Convolution2DTransposeBias padding %d" % padding)
        self.add("ConvTranspose", ["t%d" % ins[0], self.weights(ins[1], [3, 0, 1, 2]),
                                   self.init(*self.const(ins[2]))], out,
                 kernel_shape=kdims[1:3], pads=pads, strides=[stride_h, stride_w])

    def op(self, op):
        code, custom = self.codes[op.scalar(0, "I")]
        ins, outs = op.ints(1), op.ints(2)
        out, x = outs[0], "t%d" % ins[0]
        if code == DEQUANTIZE:
            self.consts[out] = self.const(ins[0])
        elif code in (CONV_2D, DEPTHWISE_CONV_2D):
            self.conv(op, ins, out, code == DEPTHWISE_CONV_2D)
        elif code in (ADD, MUL):
            self.add("Add" if code == ADD else "Mul", [x, "t%d" % ins[1]], out,
                     op.table(4).scalar(0, "b"))
        elif code in (RELU, HARD_SWISH, LOGISTIC):
            self.add({RELU: "Relu", HARD_SWISH: "HardSwish", LOGISTIC: "Sigmoid"}[code], [x], out)
        elif code == AVERAGE_POOL_2D:
            o = op.table(4)
            kernel, strides = [o.scalar(4, "i"), o.scalar(3, "i")], [o.scalar(2, "i"), o.scalar(1, "i")]
            _, h, w, _ = self.shape(ins[0])
            pads = [0, 0, 0, 0]
            if PADDING[o.scalar(0, "b")] == "SAME":
                (t, b), (l, r) = same_pads(h, kernel[0], strides[0]), same_pads(w, kernel[1], strides[1])
                pads = [t, l, b, r]
            self.add("AveragePool", [x], out, o.scalar(5, "b"), count_include_pad=0,
                     kernel_shape=kernel, pads=pads, strides=strides)
        elif code == MEAN:
            nchw = {0: 0, 1: 2, 2: 3, 3: 1}
            axes = sorted(nchw[a % 4] for a in self.const(ins[1])[1])
            self.add("ReduceMean", [x], out, axes=axes,
                     keepdims=int(op.table(4).scalar(0, "b")))
        elif code == RESIZE_BILINEAR:
            o = op.table(4)
            mode = "align_corners" if o.scalar(2, "b") else "half_pixel" if o.scalar(3, "b") else "asymmetric"
            n, h, w, c = self.shape(out)
            self.add("Resize", [x, "", "", self.init([4], [n, c, h, w], "q")], out,
                     coordinate_transformation_mode=mode, mode="linear")
        elif code == CUSTOM and custom == "Convolution2DTransposeBias":
            self.transpose_conv_bias(op, ins, out)
        else:
            sys.exit("tflite-onnx: operator %d %s is not supported" % (code, custom))

    def convert(self):
        (inp,), (outp,) = self.graph.ints(1), self.graph.ints(2)
        self.add("Transpose", ["input"], inp, perm=[0, 3, 1, 2])
        for op in self.graph.tables(3):
            self.op(op)
        self.add("Transpose", ["t%d" % outp], "mask", perm=[0, 2, 3, 1])
        graph = (b"".join(pbytes(1, n) for n in self.nodes) + pbytes(2, "selfie_segmentation")
                 + b"".join(pbytes(5, t) for t in self.inits)
                 + pbytes(11, value_info("input", self.shape(inp)))
                 + pbytes(12, value_info("mask", self.shape(outp))))
        opset = pbytes(1, "") + pint(2, 17)
        return pint(1, 8) + pbytes(2, "keyframer tflite-onnx") + pbytes(7, graph) + pbytes(8, opset)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__.splitlines()[-1])
    with open(sys.argv[1], "rb") as f:
        onnx = Converter(f.read()).convert()
    with open(sys.argv[2], "wb") as f:
        f.write(onnx)


if __name__ == "__main__":
    main()
