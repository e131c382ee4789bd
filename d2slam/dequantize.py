"""Float YOLOv8n-seg models derived from the dynamic-int8 file: int8 convolutions folded back into float ones.

The int8 file (``yolov8n-seg_int8.onnx``, onnxruntime dynamic quantization) runs every convolution as
``DynamicQuantizeLinear(x) -> ConvInteger(x_q, w_q, x_zp, w_zp) -> Cast -> Mul(x_scale * w_scale) -> Add(bias)``.
:func:`dequantize` replaces each such chain by one float ``Conv(x, (w_q - w_zp) * w_scale)`` followed by the same
bias ``Add``, drops the activation quantizers, and fixes the input to ``1x3xHxW``. The detection head's constants
that depend on the input size (DFL reshape lengths, anchor centres, anchor strides) are rebuilt for ``HxW``.
Everything else (node names, initializer order, metadata) is kept, so the output is the same bytes each time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Metadata ``onnx.infer`` of a derived file (says what was done to the weights).
DEQUANT_NOTE = "dequantized from dynamic int8 (ConvInteger -> Conv fp32)"
#: YOLOv8 detection strides (feature-map cell size of the three heads, input pixels).
HEAD_STRIDES = (8, 16, 32)
# Head constants that depend on the input size.
_DFL_SHAPE = "/model.22/dfl/Constant_output_0"
_DFL_SHAPE_1 = "/model.22/dfl/Constant_1_output_0"
_ANCHORS = ("/model.22/Constant_15_output_0", "/model.22/Constant_16_output_0")
_STRIDES = "/model.22/Constant_18_output_0"


def anchor_grid(height: int, width: int, strides=HEAD_STRIDES) -> tuple[np.ndarray, np.ndarray]:
    """YOLOv8 anchor centres ``(1, 2, N)`` (x, y in cells + 0.5, heads in stride order, rows then columns) and
    their strides ``(1, N)``, float32, for an input of ``height x width``."""
    points, steps = [], []
    for s in strides:
        ys, xs = np.meshgrid(np.arange(height // s) + 0.5, np.arange(width // s) + 0.5, indexing="ij")
        points.append(np.stack([xs.ravel(), ys.ravel()]))
        steps.append(np.full(xs.size, s))
    return (np.concatenate(points, axis=1)[None].astype(np.float32),
            np.concatenate(steps)[None].astype(np.float32))


def dequantize(model, height: int, width: int):
    """A float copy of the dynamic-int8 YOLOv8-seg ``model`` (``onnx.ModelProto``) with input ``1x3xHxW``."""
    import onnx
    from onnx import numpy_helper

    if height % max(HEAD_STRIDES) or width % max(HEAD_STRIDES):
        raise ValueError(f"input {height}x{width} is not a multiple of {max(HEAD_STRIDES)}")
    out = onnx.ModelProto()
    out.CopyFrom(model)
    graph = out.graph
    replace, drop, drop_inits, new_inits = _float_convolutions(graph)
    if not replace:
        raise ValueError("no ConvInteger node: not a dynamic-int8 model")
    nodes = [replace.get(k, n) for k, n in enumerate(graph.node) if k not in drop]
    del graph.node[:]
    graph.node.extend(nodes)
    kept = [t for t in graph.initializer if t.name not in drop_inits]
    anchors, strides = anchor_grid(height, width)
    fixed = {_DFL_SHAPE: np.array([1, 4, 16, -1], np.int64), _DFL_SHAPE_1: np.array([1, 4, -1], np.int64),
             _STRIDES: strides, **{name: anchors for name in _ANCHORS}}
    kept = [numpy_helper.from_array(fixed[t.name], t.name) if t.name in fixed else t for t in kept]
    del graph.initializer[:]
    graph.initializer.extend(kept + new_inits)
    _set_input_size(out, height, width)
    return out


def _float_convolutions(graph) -> tuple[dict, set, set, list]:
    """Each dynamic-int8 convolution chain of ``graph`` (DynamicQuantizeLinear -> ConvInteger -> Cast -> Mul) as one
    float Conv with dequantized weights: (node index -> its Conv, the chain's other node indices to drop, the int8
    initializers to drop, the float weights to add)."""
    from onnx import helper, numpy_helper

    inits = {t.name: t for t in graph.initializer}
    producers = {o: n for n in graph.node for o in n.output}
    consumers: dict[str, list] = {}
    for n in graph.node:
        for i in n.input:
            consumers.setdefault(i, []).append(n)
    idx = {id(n): k for k, n in enumerate(graph.node)}
    drop: set[int] = set()
    replace: dict[int, object] = {}
    drop_inits: set[str] = set()
    new_inits = []
    for conv in graph.node:
        if conv.op_type != "ConvInteger":
            continue
        x_q, w_q, _x_zp, w_zp = conv.input
        quantizer = producers[x_q]  # DynamicQuantizeLinear(x) -> x_q, x_scale, x_zp
        cast = consumers[conv.output[0]][0]
        scaled = consumers[cast.output[0]][0]  # Mul(cast, x_scale * w_scale)
        scale_mul = producers[scaled.input[1]]
        w_scale = scale_mul.input[1]
        if quantizer.op_type != "DynamicQuantizeLinear" or cast.op_type != "Cast" or scaled.op_type != "Mul":
            raise ValueError(f"{conv.name}: not a dynamic-int8 convolution chain")
        base = w_q[: -len("_quantized")]
        weight = ((numpy_helper.to_array(inits[w_q]).astype(np.float32)
                   - numpy_helper.to_array(inits[w_zp]).astype(np.float32))
                  * numpy_helper.to_array(inits[w_scale]).astype(np.float32))
        new_inits.append(numpy_helper.from_array(weight.astype(np.float32), base + "_dequant"))
        drop_inits.update((w_q, w_zp, w_scale))
        node = helper.make_node("Conv", [quantizer.input[0], base + "_dequant"], [scaled.output[0]],
                                name=conv.name + "_f32")
        node.attribute.extend(conv.attribute)
        replace[idx[id(conv)]] = node
        drop.update(idx[id(n)] for n in (quantizer, cast, scaled, scale_mul))
    return replace, drop, drop_inits, new_inits


def _set_input_size(out, height: int, width: int) -> None:
    """The model's input ``1x3xHxW``, its outputs' sizes left to inference, its metadata saying so."""
    graph = out.graph
    dims = graph.input[0].type.tensor_type.shape.dim
    dims[2].dim_value, dims[3].dim_value = int(height), int(width)
    del graph.value_info[:]
    for o in graph.output:
        for k, d in enumerate(o.type.tensor_type.shape.dim):
            if k > 0:
                d.Clear()
                d.dim_param = f"{o.name}_d{k}"
    for p in out.metadata_props:
        if p.key == "onnx.infer":
            p.value = DEQUANT_NOTE
        elif p.key == "imgsz":
            p.value = f"[{int(height)}, {int(width)}]"


def dequantize_file(src: str | Path, dst: str | Path, height: int, width: int) -> Path:
    """Read the int8 file ``src``, write its float ``height x width`` copy to ``dst`` (through a temporary file)."""
    import onnx

    dst = Path(dst)
    tmp = dst.with_name(dst.name + ".tmp")
    tmp.write_bytes(dequantize(onnx.load(str(src)), height, width).SerializeToString())
    tmp.replace(dst)
    return dst
