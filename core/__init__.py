"""The plumbing every part of depotbench shares: errors that name the bad input, bounded
file reading, output folders that never lose a user's data, worker pools, child processes
that end with their parent, cache locations and the versions outputs record. It imports
nothing else of depotbench."""
