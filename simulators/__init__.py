"""Simulated devices for dry runs and tests: the excitation system (Modbus TCP) and the recorder
(Modbus RTU on a pseudo-terminal and RTU-over-TCP) around one real-time plant, with fault
injection. Entry point: `simulators.bench.SimBench`; command line: `bench-ctl sim`.

Modules: bench (life cycle, endpoints), exciter / recorder (device logic on register names),
regmap (profile <-> Modbus requests), modbus (pymodbus servers with reply faults), faults,
pty_bridge (serial line), control (run-time fault port of `bench-ctl sim`).
"""
