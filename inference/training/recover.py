"""Trainable torch networks recovered from a served model folder's ONNX files.

A model folder (the shipped one, or an adaptation's) holds only what the service runs: UNet++
quantised to int8 with its batch norms folded into the convolutions, Swin with its large weights
in float16 and the linear layers' weights transposed into anonymous MatMul constants. Adapting
to a radar starts from those weights, so they are read back here:

* UNet++: each Conv / ConvTranspose node's weight (dequantised: ``(q - zero_point) * scale`` per
  channel) and bias, matched to the torch network's convolutions by the node's scope (the module
  that exported it), every shape checked. The batch norms are folded, so the network is
  rebuilt without them (``unet_norm = False``): the same function, with the folded weights.
* Swin: weights that kept their names load by name; the rest by the scope of the node that uses
  them (``scope``): a linear layer's weight is its MatMul's constant (transposed), a window
  attention's bias table the constant added to its scores ([1, heads, N, N], the table gathered
  by ``relative_position_index``; inverted here, since every table entry is gathered somewhere).

``recover`` then checks the recovered networks against ONNX Runtime on the card's self-check
frame and on seeded frames: Swin within float16's rounding, UNet++ within what int8 changes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from inference.errors import ModelFileError
from inference.networks.build import build_models, config_from_dict
from inference.networks.swin import WindowAttention

SWIN_PARITY = 5e-3  # max |ONNX - torch| in the scaled angle (0.2 deg): float16 weights round at 1e-3 relative
UNET_PARITY = 0.02  # mean |ONNX int8 - torch float| of the enhanced frame (the shipped set's int8 moved it 0.005)


class _Graph:
    """An ONNX graph's constants: initializers, Constant nodes, and what Identity, Cast and DequantizeLinear make of them."""

    def __init__(self, path: Path) -> None:
        import onnx
        from onnx import numpy_helper

        try:
            model = onnx.load(str(path))
        except Exception as exc:  # onnx raises its own DecodeError and others
            raise ModelFileError(f"{path} cannot be read as ONNX: {exc}", field="model") from None
        self.nodes = list(model.graph.node)
        self.values: dict[str, NDArray[Any]] = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
        self.producer = {out: n for n in self.nodes for out in n.output}
        for n in self.nodes:
            if n.op_type == "Constant" and n.attribute and n.attribute[0].name == "value":
                self.values[n.output[0]] = numpy_helper.to_array(n.attribute[0].t)

    def const(self, name: str) -> NDArray[np.float32] | None:
        """The value of ``name`` when it is a constant (through Cast and DequantizeLinear), else None."""
        if name in self.values:
            return np.asarray(self.values[name])
        node = self.producer.get(name)
        if node is None:
            return None
        if node.op_type == "Identity":  # the exporter shares equal constants through Identity nodes
            return self.const(node.input[0])
        if node.op_type == "Cast":
            v = self.const(node.input[0])
            return None if v is None else v.astype(np.float32)
        if node.op_type == "DequantizeLinear":
            q = self.const(node.input[0])
            scale = self.const(node.input[1])
            zero = self.const(node.input[2]) if len(node.input) > 2 and node.input[2] else None
            if q is None or scale is None:
                return None
            axis = next((a.i for a in node.attribute if a.name == "axis"), 1)
            shape = [1] * q.ndim
            if scale.ndim == 1 and scale.size > 1:
                shape[axis] = scale.size
            z = np.zeros(1) if zero is None else zero.astype(np.float64).reshape(shape)
            return ((q.astype(np.float64) - z) * scale.astype(np.float64).reshape(shape)).astype(np.float32)
        return None


def scope(node_name: str) -> str:
    """The torch module a node of ``torch.onnx.export`` came from: ``/stages/stages.0/blocks/blocks.1/attn/qkv/MatMul``
    is ``stages.0.blocks.1.attn.qkv`` (the exporter writes each ModuleList / ModuleDict level twice)."""
    path: list[str] = []
    for seg in node_name.strip("/").split("/")[:-1]:
        if path and seg.startswith(path[-1] + "."):
            path[-1] = seg
        else:
            path.append(seg)
    return ".".join(path)


def _set(param: torch.Tensor, value: NDArray[Any], what: str) -> None:
    if tuple(param.shape) != tuple(value.shape):
        raise ModelFileError(
            f"{what}: the ONNX file's weight is {list(value.shape)}, the network's {list(param.shape)}: the card's "
            "config does not describe this file",
            field="model",
        )
    with torch.no_grad():
        param.copy_(torch.from_numpy(np.array(value, np.float32)))


def recover_unet(path: Path, cfg: dict[str, Any]) -> torch.nn.Module:
    """UNet++ from its ONNX file (int8 or float, batch norm folded or not), rebuilt without batch norm.

    Each convolution node's scope names its module: ``/0_1/block/block.3/Conv`` is node 0_1's second
    convolution (whatever its index with batch norm between), ``/0_1/ConvTranspose`` the up-sampling
    into node 0_1, ``/heads.2/Conv`` a head.
    """
    g = _Graph(path)
    plain = config_from_dict({**cfg, "unet_norm": False})
    unet, _ = build_models(plain)
    found: dict[str, list[tuple[int, Any]]] = {}
    for n in g.nodes:
        if n.op_type == "ConvTranspose":
            found.setdefault(f"ups.{scope(n.name)}", []).append((0, n))
        elif n.op_type == "Conv":
            where = scope(n.name)
            if where.startswith("heads."):
                found.setdefault(where, []).append((0, n))
            else:  # "0_1.block.3" -> node 0_1, ordered by the layer index
                key, _, layer = where.partition(".block.")
                found.setdefault(f"nodes.{key}", []).append((int(layer or 0), n))
    targets: dict[str, list[torch.nn.Conv2d | torch.nn.ConvTranspose2d]] = {}
    for name, m in unet.named_modules():
        if isinstance(m, torch.nn.ConvTranspose2d | torch.nn.Conv2d):
            owner = name.rsplit(".block.", 1)[0] if ".block." in name else name
            targets.setdefault(owner, []).append(m)
    if sorted(found) != sorted(targets):
        raise ModelFileError(
            f"{path.name}'s convolutions ({len(found)} modules) are not the configured UNet++'s ({len(targets)})",
            field="model",
        )
    for owner, convs in targets.items():
        nodes = [n for _, n in sorted(found[owner], key=lambda t: t[0])]
        if len(nodes) != len(convs):
            raise ModelFileError(f"{path.name}: {owner} has {len(nodes)} convolutions, not {len(convs)}", field="model")
        for k, (node, conv) in enumerate(zip(nodes, convs, strict=True)):
            w = g.const(node.input[1])
            b = g.const(node.input[2]) if len(node.input) > 2 and node.input[2] else None
            if w is None:
                raise ModelFileError(f"{path.name}: {owner} convolution {k}'s weight is not a constant", field="model")
            _set(conv.weight, w, f"{path.name} {owner} convolution {k}")
            assert conv.bias is not None  # built without batch norm: every convolution has a bias
            _set(
                conv.bias, b if b is not None else np.zeros(tuple(conv.bias.shape), np.float32), f"{path.name} {owner}"
            )
    unet.eval()
    return unet


def _bias_table(bias: NDArray[Any], attn: WindowAttention) -> NDArray[np.float32]:
    """Invert ``bias_table[bias_index]``: the table from the gathered bias [1, heads, N, N]."""
    heads, n = attn.num_heads, attn.n
    b = bias.reshape(heads, n * n).T  # [N * N, heads], row i * N + j
    table = np.zeros(tuple(attn.bias_table.shape), np.float32)
    idx = attn.bias_index.numpy()
    table[idx] = b
    if len(np.unique(idx)) != table.shape[0]:
        raise ModelFileError("a bias table entry is never gathered: it cannot be recovered", field="model")
    return table


def recover_swin(path: Path, cfg: dict[str, Any]) -> torch.nn.Module:
    """Swin from its ONNX file: named weights by name, the rest in the order they run (see the module's text)."""
    g = _Graph(path)
    conf = config_from_dict(cfg)
    _, swin = build_models(conf)
    state = swin.state_dict()
    named = {}
    for name in state:
        for cand in (name, f"{name}__fp16"):
            v = g.const(cand) if cand in g.values else None
            if v is None and cand == name and name in g.producer:
                v = g.const(name)
            if v is not None:
                named[name] = v
                break
    params = dict(swin.named_parameters())
    modules = dict(swin.named_modules())
    done: set[str] = set()

    def place(key: str, value: NDArray[Any] | None) -> None:
        if value is not None and key in params and key not in done and tuple(params[key].shape) == value.shape:
            _set(params[key], value, f"{path.name} {key}")
            done.add(key)

    for n in g.nodes:  # by the scope of the node that uses the weight (the exporter may share equal constants)
        where = scope(n.name)
        consts = [g.const(i) if i else None for i in n.input]
        if n.op_type == "MatMul" and consts[1] is not None:
            place(f"{where}.weight", consts[1].T)
        elif n.op_type in ("LayerNormalization", "Conv"):
            place(f"{where}.weight", consts[1])
            if len(consts) > 2:
                place(f"{where}.bias", consts[2])
        elif n.op_type == "Gemm":
            trans_b = next((a.i for a in n.attribute if a.name == "transB"), 0)
            if consts[1] is not None:
                place(f"{where}.weight", consts[1] if trans_b else consts[1].T)
            if len(consts) > 2:
                place(f"{where}.bias", consts[2])
        elif n.op_type == "Add":
            attn = modules.get(where)
            for c in consts:
                if c is None:
                    continue
                if isinstance(attn, WindowAttention) and c.shape == (1, attn.num_heads, attn.n, attn.n):
                    key = f"{where}.bias_table"
                    _set(attn.bias_table, _bias_table(c, attn), f"{path.name} {key}")
                    done.add(key)
                elif isinstance(attn, torch.nn.Linear):
                    place(f"{where}.bias", c)
    for key, v in named.items():  # what kept its name and no node's scope placed
        place(key, v)
    missing = [k for k, _ in swin.named_parameters() if k not in done]
    if missing:
        raise ModelFileError(f"{path.name}: no weight found for {', '.join(missing[:3])}", field="model")
    swin.eval()
    return swin


def recover(model_dir: str | Path) -> tuple[torch.nn.Module, torch.nn.Module, dict[str, Any], dict[str, float]]:
    """UNet++ and Swin of a model folder as torch networks, checked against ONNX Runtime.

    Returns the networks, the config they were built from (``unet_norm`` False: the batch norms are
    folded in) and the parity figures. Raises ModelFileError when the folder is not a set of
    enhanced networks or the recovered networks do not compute what the files do.
    """
    import onnxruntime as ort

    from inference.runtime import read_card, selfcheck_frames

    d = Path(model_dir)
    card = read_card(d)
    if not card.get("enhance", True):
        raise ModelFileError(f"{d}: its Swin reads raw frames; adaptation needs a set with UNet++", field="model")
    cfg = dict(card["config"])
    unet = recover_unet(d / "unetpp.onnx", cfg)
    swin = recover_swin(d / "swin.onnx", cfg)
    size = int(cfg["img_size"])
    x = np.concatenate([selfcheck_frames(size), np.random.default_rng(1).random((1, 1, size, size), np.float32)])
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    sessions = {
        r: ort.InferenceSession(str(d / f"{r}.onnx"), opts, providers=["CPUExecutionProvider"])
        for r in ("unetpp", "swin")
    }
    with torch.no_grad():
        enh = unet(torch.from_numpy(x))
        ang = swin(enh).numpy()
    enh_ort = sessions["unetpp"].run(None, {"frame": x})[0]
    ang_ort = sessions["swin"].run(None, {"frame": enh.numpy()})[0]
    figures = {
        "unetpp_mean_abs_diff": float(np.abs(enh_ort - enh.numpy()).mean()),
        "swin_max_abs_diff": float(np.abs(ang_ort - ang).max()),
    }
    if figures["unetpp_mean_abs_diff"] > UNET_PARITY or figures["swin_max_abs_diff"] > SWIN_PARITY:
        raise ModelFileError(
            f"{d}: the networks read back from the ONNX files do not compute what the files do ({figures})",
            field="model",
        )
    plain = config_from_dict({**cfg, "unet_norm": False}).as_dict()
    return unet, swin, plain, figures
