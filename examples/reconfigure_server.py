"""A dynamic_reconfigure server: tune ``/camera``'s exposure, gain, mode and name at run time.

    python examples/reconfigure_server.py [__name:=camera]
    mros reconfigure set /camera exposure 20          # or: rosrun dynamic_reconfigure dynparam set /camera exposure 20

The callback may adjust what it is given (here: exposure rounded to a multiple of 5); clients see the result.
"""

from __future__ import annotations

from typing import Any

import mrosd
from mrosd.reconfigure import Description, EnumConstant, GroupSpec, Param, ReconfigureServer

DESCRIPTION = Description(
    [
        GroupSpec(
            "Default",
            0,
            params=[
                Param("exposure", "int", 10, min=1, max=1000, level=1, description="Exposure (ms)"),
                Param("gain", "double", 1.0, min=0.0, max=16.0, level=2, description="Analog gain"),
                Param("auto", "bool", False, level=4, description="Automatic exposure"),
                Param(
                    "mode",
                    "int",
                    0,
                    min=0,
                    max=2,
                    level=8,
                    description="Sensor mode",
                    enum=(EnumConstant("Full", 0, "full frame"), EnumConstant("Binned", 1), EnumConstant("Roi", 2)),
                    enum_description="Readout mode",
                ),
            ],
        ),
        GroupSpec("Info", 1, parent=0, params=[Param("name", "str", "camera", description="Label")]),
    ]
)


def reconfigure(config: dict[str, Any], level: int) -> dict[str, Any]:
    config["exposure"] = max(5, round(config["exposure"] / 5) * 5)
    print(f"level {level:#x}: {config}", flush=True)
    return config


async def main() -> None:
    async with mrosd.Node("camera") as node, ReconfigureServer(node, DESCRIPTION, reconfigure):
        await node.spin()


if __name__ == "__main__":
    mrosd.run(main)
