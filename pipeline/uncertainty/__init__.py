"""What the fits hold as exact, carried to their estimates' std as consider parameters
(:mod:`.consider`): refits through callables the jobs pass in."""
