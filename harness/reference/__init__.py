"""References nobody here wrote, and reports against them: SUMO's NEMA controller (the
differential), field controllers' hi-res logs through Signal-Replay, sumo-rl on RESCO's
networks, the paper's figures."""
