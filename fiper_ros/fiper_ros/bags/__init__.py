"""Bags of the FIPER suite: schema, reading and writing, record / replay / snapshot, calibration from
bags, converters from the reference datasets' layouts, and the sample data (docs/bags.md).

Bags are rosbag2 directories (``metadata.yaml`` + one MCAP file, format version 9) written with
``rosbags``; nothing here needs ``ros2 bag``, which the pip wheels do not provide.
"""
