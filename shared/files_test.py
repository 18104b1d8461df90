import json

from shared.files import write_json


def test_a_json_file_is_written_whole_in_a_directory_made_for_it(tmp_path):
    path = tmp_path / "made" / "record.json"
    write_json(path, {"b": 1, "a": [1, 2]})
    assert path.read_text() == json.dumps({"b": 1, "a": [1, 2]}, indent=1) + "\n"
    write_json(path, {"c": 3})
    assert json.loads(path.read_text()) == {"c": 3}
    assert [p.name for p in path.parent.iterdir()] == ["record.json"]  # no .partial left behind
