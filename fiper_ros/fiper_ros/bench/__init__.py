"""Benchmarks of the fiper-ros suite."""

#: The alarm contract keeps only the newest state (KEEP_LAST(1)); to count every step's alarm a benchmark
#: deepens the fusion node's history with the standard QoS override parameter.
EVERY_ALARM = {"qos_overrides./fiper/alarm.publisher.depth": 1000}
