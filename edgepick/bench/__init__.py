"""`edgepick bench`: thesis Table 5.5 (accuracy, latency, training time, size per model) and the
Table 5.6 analogue (whole pipeline time per frame), measured in one process. No torch."""
