"""Distributed sqpmpc services over Eclipse Zenoh.

Run ``python -m services.<name>``:

- :mod:`services.launch` - plant and controllers as local processes (the default way);
- :mod:`services.plant` - holds the true state, applies the inputs, writes the outputs;
- :mod:`services.robot` - one robot's decentralized controller;
- :mod:`services.central` - the centralized controller for every robot;
- :mod:`services.router` - a Zenoh router (for docker-compose or several hosts).

:mod:`services.credentials` (``sqpmpc credentials``) writes a run's
certificates and Zenoh configs: mutual TLS and access control;
:mod:`services.handover` hands each process of a launch only its own, in
memory; :mod:`services.limits` drops oversized and too frequent messages in
Zenoh's interceptors; :mod:`services.early` keeps a stop during start-up from
ending a process with a traceback.

The wire schema is in :mod:`services.messages`, the key space and the Zenoh
session in :mod:`services.transport`.
"""

__all__: list[str] = []
