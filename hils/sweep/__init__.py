"""Many runs: a grid of agents x seeds x scenarios, each cell one `hils run`, on a process pool or on
Ray; and the comparison of agents over seeds with confidence intervals."""
