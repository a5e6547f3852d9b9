"""The oracles the path engine is tested against: the paper's literal Algorithm 2
(:mod:`~sonarsim.reference.algorithm2`, the ground alone; also ``render.method: paper``) and a
brute-force reference of the path model over any planes
(:mod:`~sonarsim.reference.brute_force`: every chain enumerated, every transmit leg verified by
tracing). Plain NumPy, slow on purpose; nothing in the engine imports them."""
