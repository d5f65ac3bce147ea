"""The part of a machine's object in the OPC UA face (`compd.faces.opcua_face`)
that its config decides: ``Terms/<term>_um``, ``Channels/<name>/Value`` and
``/Valid``, ``Model/Name`` and ``Model/Sha256``, the ``Adaptation`` folder, and
with ``[output.axes]`` the ``Axes`` folder, one object per axis (``Axes/X``,
its variables `AXIS_VARIABLES`).

`shape` builds them when the machine's object is added, and makes them match
a reloaded config: the nodes of a term or channel no longer there are
deleted, new ones added (NaN, invalid, until the next cycle is published),
the model's name and sha256 written, the Adaptation folder and each axis's
folder added or deleted.
Every other node (``Offset_um``, ``FaultState``, the methods...) stays as it
is, so a client's subscription to it goes on across a reload. It runs on the
face's own loop, in the task that writes the values.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from asyncua import ua
from asyncua.ua.status_codes import StatusCodes

if TYPE_CHECKING:
    from asyncua.common.node import Node
    from asyncua.server.server import Server

    from compd.config.loader import LoadedConfig

__all__ = ["ADAPTATION_NAMES", "AXIS_VARIABLES", "MachineNodes", "axis_path"]

#: the adaptation estimator's variables, under Adaptation/
ADAPTATION_NAMES: tuple[str, ...] = ("Bias_um", "BiasSigma_um", "Correction_um")

_D, _B, _S, _U = (ua.VariantType.Double, ua.VariantType.Boolean, ua.VariantType.String,
                  ua.VariantType.UInt32)
#: each axis's variables under Axes/<AXIS>/ and their types: the line the controller
#: holds (its value at the reference position and its slope, as confirmed), what the
#: axis's models ask, whether the line compd wants is in force, the axis's state,
#: cause and status word (the bits of ``StatusWord``), its reference position, and
#: for an axis written as one offset at its read position that position and the
#: offset sent at it (NaN for an axis written as the line's parameters)
AXIS_VARIABLES: dict[str, ua.VariantType] = {
    "Value_um": _D, "Slope_um_m": _D, "ValueModel_um": _D, "SlopeModel_um_m": _D,
    "InForce": _B, "FaultStateName": _S, "Cause": _S, "StatusWord": _U,
    "ReferencePosition_mm": _D, "Position_mm": _D, "Offset_um": _D}
_INITIAL: dict[ua.VariantType, Any] = {_D: math.nan, _B: False, _S: "starting", _U: 0}


def axis_path(axis: str, name: str = "") -> str:
    """The path of an axis's folder ("Axes.X") or of one of its variables."""
    return f"Axes.{axis.upper()}" + (f".{name}" if name else "")


class MachineNodes:
    """One machine's object and its variables by path ("Terms.spindle")."""

    def __init__(self, server: Server, idx: int, name: str, obj: Node,
                 nodes: dict[str, Node]) -> None:
        self.server = server
        self.idx = idx
        self.name = name
        self.obj = obj
        self.nodes = nodes
        #: the Axes folder while the config has [output.axes]
        self.axes_folder: Node | None = None

    def nid(self, path: str) -> ua.NodeId:
        return ua.NodeId(ua.String(f"{self.name}.{path}"), ua.Int16(self.idx))

    async def var(self, parent: Node, path: str, name: str, value: Any,
                  vtype: ua.VariantType, datatype: ua.NodeId | None = None) -> None:
        node = await parent.add_variable(self.nid(path), ua.QualifiedName(name, self.idx),
                                         ua.Variant(value, vtype), datatype=datatype)
        self.nodes[path] = node

    async def folder(self, parent: Node, path: str, name: str) -> Node:
        return await parent.add_folder(self.nid(path), ua.QualifiedName(name, self.idx))

    async def _delete(self, path: str, *children: str) -> None:
        """The node at `path` and everything under it; `children`: its variables
        (forgotten once deleted: a failed delete is tried again at the next shape)."""
        _, results = await self.server.delete_nodes([self.server.get_node(self.nid(path))],
                                                    recursive=True)
        for status in results:
            if status.value != StatusCodes.BadNodeIdUnknown:  # gone already: deleted
                status.check()
        for child in (path, *children):
            self.nodes.pop(child, None)

    async def shape(self, cfg: LoadedConfig) -> None:
        """Make the config's part of the object match `cfg` (the module docstring);
        the Terms, Channels and Model folders exist already."""
        nan, double = math.nan, ua.VariantType.Double
        terms = {f"Terms.{t.name}": f"{t.name}_um" for t in cfg.model.terms}
        for path in [p for p in self.nodes if p.startswith("Terms.") and p not in terms]:
            await self._delete(path)
        folder = self.server.get_node(self.nid("Terms"))
        for path, name in terms.items():
            if path not in self.nodes:
                await self.var(folder, path, name, nan, double)

        have = {p.removeprefix("Channels.").removesuffix(".Value") for p in self.nodes
                if p.startswith("Channels.") and p.endswith(".Value")}
        for ch in sorted(have - set(cfg.channels)):
            await self._delete(f"Channels.{ch}", f"Channels.{ch}.Value",
                               f"Channels.{ch}.Valid")
        channels = self.server.get_node(self.nid("Channels"))
        for ch in cfg.channels:
            if ch not in have:
                sub = await self.folder(channels, f"Channels.{ch}", ch)
                await self.var(sub, f"Channels.{ch}.Value", "Value", nan, double)
                await self.var(sub, f"Channels.{ch}.Valid", "Valid", False,
                               ua.VariantType.Boolean)

        model = {"Model.Name": cfg.model.name, "Model.Sha256": cfg.model_sha256}
        for path, value in model.items():
            node = self.nodes.get(path)
            if node is None:
                await self.var(self.server.get_node(self.nid("Model")), path,
                               path.removeprefix("Model."), value, ua.VariantType.String)
            else:
                await node.write_value(ua.DataValue(ua.Variant(value, ua.VariantType.String)))

        await self._shape_axes(cfg)
        adapting = f"Adaptation.{ADAPTATION_NAMES[0]}" in self.nodes
        if adapting and cfg.adaptation is None:
            await self._delete("Adaptation", *(f"Adaptation.{n}" for n in ADAPTATION_NAMES))
        elif not adapting and cfg.adaptation is not None:
            ad = await self.folder(self.obj, "Adaptation", "Adaptation")
            for name in ADAPTATION_NAMES:
                await self.var(ad, f"Adaptation.{name}", name, nan, double)

    async def _shape_axes(self, cfg: LoadedConfig) -> None:
        """The Axes folder and one folder per ``[output.axes]`` axis, as `cfg` has them."""
        wanted = set(cfg.axes.axes) if cfg.axes is not None else set()
        first = next(iter(AXIS_VARIABLES))
        have = {p.split(".")[1].lower() for p in self.nodes
                if p.startswith("Axes.") and p.endswith(f".{first}")}
        for axis in sorted(have - wanted):
            await self._delete(axis_path(axis), *(axis_path(axis, n) for n in AXIS_VARIABLES))
        if not wanted:
            if self.axes_folder is not None:
                await self._delete("Axes")
                self.axes_folder = None
            return
        folder = self.axes_folder
        if folder is None:
            folder = self.axes_folder = await self.folder(self.obj, "Axes", "Axes")
        for axis in sorted(wanted - have):
            sub = await self.folder(folder, axis_path(axis), axis.upper())
            for name, vtype in AXIS_VARIABLES.items():
                await self.var(sub, axis_path(axis, name), name, _INITIAL[vtype], vtype)
