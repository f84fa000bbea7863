"""The fleet interface: the truck as a VDA 5050 2.1 vehicle (``agf serve``, docs/fleet.md).

Pure logic: messages and their checks (:mod:`agf.fleet.messages`), the ``pick`` action's parameters
(:mod:`agf.fleet.pick`), the vehicle's order, action and state handling (:mod:`agf.fleet.agent`) and
the protocols its transport (:mod:`agf.fleet.link`) and its truck (:mod:`agf.fleet.truck`) implement.
The MQTT transport and the simulated truck live in ``drivers/``, chosen by ``plugins.fleet`` and
``plugins.fleet_truck``.
"""
