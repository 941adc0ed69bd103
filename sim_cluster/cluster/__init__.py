"""The process cluster: ``launcher`` (the Cluster), ``configs`` (the camera configs it writes),
``state`` (its state file and the nodes' status files), ``processes`` (ports, spawning, ending),
``monitor`` (a passive Zenoh subscriber counting link bytes), ``commands`` (up, status, kill,
restart, down).
"""
