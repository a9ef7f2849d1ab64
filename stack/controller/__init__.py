"""The software CAN controller: fault confinement, transmit queues, acceptance filters, the node,
its events, the node API that profiles and ECUs are written against, and the contract a driver
(the simulated bus, a python-can bus) fulfils. It imports only `stack.wire`."""
