"""Browser-facing protocols: the Foxglove WebSocket protocol served from the daemon (``[web]``) or ``mros bridge``.

A client of the same graph watch and raw TCPROS bodies as everything else, never a second data path:
``hub`` (the ROS side, shared by every client), ``foxglove`` (the pure protocol core), ``foxglove_server``
(one session per WebSocket), ``queue`` (per-client byte bounds), ``access`` (allow-lists, token), ``assets``
(fetchAsset from ROS packages), ``server`` (the listener). See docs/web.md.
"""
