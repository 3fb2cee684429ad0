"""The car in one process on a virtual clock (issue 27): what the lockstep runner plugs in
where the car has real devices and sockets. links.py: serial twins reached as ``mem://NAME``.

Nothing is imported here, so a driver opening a ``mem://`` link loads only what it uses.
"""
