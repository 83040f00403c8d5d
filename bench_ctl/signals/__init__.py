"""Analysis of recorded signals: setpoint edges, the electromechanical mode, acceptance windows."""
