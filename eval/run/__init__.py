"""One sequence through one detector and one tracker: the job, its cached stages
(detections, features, flow), the run itself and the files it leaves."""
