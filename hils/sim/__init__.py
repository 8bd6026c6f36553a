"""SUMO: the simulation the Testbed steps, the networks and the phase of each signal link, RESCO's
figures from SUMO's tripinfo, Webster's fixed-time plan for a network's demand."""
