"""YAML the project writes: plain data, libyaml's emitter when PyYAML has it."""

from __future__ import annotations

import math

import yaml

from thruster_fdd.core.safe_yaml import dump_yaml, load_yaml

SAMPLE = {
    "rosbag2_bagfile_information": {
        "version": 9,
        "relative_file_paths": ["up_0.mcap", "up_1.mcap"],
        "duration": {"nanoseconds": 123_456_789_012},
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": "/thruster/t0/esc/telemetry",
                    "offered_qos_profiles": "- history: keep_last\n  depth: 10\n",
                    "type_description_hash": "RIHS01_" + "ab" * 32,
                },
                "message_count": 4096,
            }
        ],
        "custom_data": {"vehicle": "sim-äuv: 'quoted' #1", "empty": "", "yes": "yes"},
        "numbers": [0.1, -2.5e-12, 1e300, math.inf, True, None, "0x1F", "1.0"],
    }
}


def test_the_text_is_the_pure_python_dumpers_and_reads_back() -> None:
    class Plain(yaml.SafeDumper):
        def ignore_aliases(self, data: object) -> bool:
            return True

    text = dump_yaml(SAMPLE)
    assert text == yaml.dump(SAMPLE, Dumper=Plain, sort_keys=False)
    assert load_yaml(text, "sample") == SAMPLE


def test_an_object_seen_twice_is_written_twice_not_as_an_alias() -> None:
    shared = {"depth": 10}
    text = dump_yaml({"a": shared, "b": shared})
    assert "&" not in text
    assert "*" not in text
    assert load_yaml(text, "shared") == {"a": shared, "b": shared}
