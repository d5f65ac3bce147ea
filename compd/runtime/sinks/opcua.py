"""compd's own OPC UA server face as a sink ([faces.opcua]): the machine's
state for the PLC and SCADA, and ``SetHold`` and ``Rezero`` for the operator.

The server starts beside the loop (`open` starts it in a task: it takes
seconds, and compensation starts at once and never waits for it); once up,
each cycle hands it the committed row, whose `snapshot` it reads
(`compd.faces.opcua_face.OpcUaFace.publish`), and the face writes it in its
own task. The config is the tick's: after a SIGHUP reload the face shows the
new config's terms, channels and model (`compd.faces.opcua_shape`). `close`
waits for a start still under way, then stops the server.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TYPE_CHECKING

from compd.runtime.sinks.base import CycleSink, Tick

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.faces.opcua_face import OpcUaFace
    from compd.faces.telemetry import Metrics

__all__ = ["OpcUaSink"]


class OpcUaSink(CycleSink):
    stage = "opcua_face"

    def __init__(self, *, metrics: Metrics, operator_hold: Callable[[bool, str], bool],
                 rezero: Callable[[str], bool] | None = None) -> None:
        self._metrics = metrics
        self._operator_hold = operator_hold
        self._rezero = rezero
        #: the face once started
        self.face: OpcUaFace | None = None
        #: its start, while under way
        self.starting: asyncio.Task[None] | None = None

    async def open(self, cfg: LoadedConfig) -> None:
        """The face at start, if the config has one (a reload may not change whether
        it runs, nor its server); every cycle's config is the tick's."""
        if not cfg.raw.faces.opcua.enabled:
            return
        from compd.faces.opcua_face import OpcUaFace

        face = OpcUaFace(cfg, self._operator_hold, self._metrics.registry,
                         rezero=self._rezero)

        async def start() -> None:
            if await face.start():
                self.face = face

        self.starting = asyncio.get_running_loop().create_task(start(),
                                                               name="opcua-face-start")

    def feed(self, tick: Tick) -> None:
        face = self.face
        if face is not None:  # a snapshot; the face writes it in its own task
            if face.cfg is not tick.cfg:  # a reload: its terms, channels and model
                face.reconfigure(tick.cfg)
            face.publish(tick.row)

    async def close(self) -> None:
        starting, self.starting = self.starting, None
        if starting is not None:
            await asyncio.gather(starting, return_exceptions=True)
        face, self.face = self.face, None
        if face is not None:
            await face.stop()
