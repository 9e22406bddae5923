"""Numbers from trajectories and rows: TUM trajectories and their association, Umeyama
alignment, ATE/RPE and the improvement rate rho as evo computes them, statistics over
seeds, and the run record every stage above fills and reads. Nothing here runs a tracker."""
