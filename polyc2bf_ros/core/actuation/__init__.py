"""Real actuation: commands turned into inputs, commands in flight, lagging actuators.

``command_interface``: velocity commands <-> acceleration inputs; ``input_delay``:
commands in flight and a lagging base; ``rotor_lag``: lagging rotors.

Imports nothing else of the core.
"""
