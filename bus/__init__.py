"""The CAN bus layer (docs/design.md section 4).

Sans-IO core: ``catalog`` (single source of truth: frames, IDs, signals, cycle times),
``dbc`` (DBC generated from it, committed as ``hil.dbc``), ``codec`` (typed messages <->
frames), ``e2e`` (CRC-8/SAE-J1850 + alive counter), ``receiver`` (classification, counters,
frame-set assembly), ``protocol`` (lockstep and heartbeat state machines), ``link`` (fake bus
for tests). I/O: ``transport`` (python-can: ``open_bus``, ``Port``, ``BusLogger``),
``echo_peer`` (test and benchmark peer), ``errors``; ``hil dbc`` lives in ``hil.dbc_cmd``.
"""
