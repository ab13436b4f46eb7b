"""The one definition of every parameter (geomodel_ros.core.params) and its YAML forms."""

from __future__ import annotations

import dataclasses
import math
import pickle
import typing
from pathlib import Path

import pytest

from geomodel_ros.tools.cli import params_yaml
from geomodel_ros.core.params import (
    PARAMETERS,
    ModelingParams,
    ParameterError,
    load_params_file,
)

CONFIG = Path(__file__).resolve().parent.parent / "config"
SPECS = {p.name: p for p in PARAMETERS}

# ---------------------------------------------------------------------------------------
# The definitions themselves
# ---------------------------------------------------------------------------------------


def test_defaults_are_valid():
    params = ModelingParams()
    for spec in PARAMETERS:
        value = getattr(params, spec.name)
        assert value == spec.default
        assert type(value) is spec.type
        assert spec.check(spec.default) == spec.default


def test_names_are_unique_and_match_the_dataclass():
    names = [p.name for p in PARAMETERS]
    assert len(names) == len(set(names))
    assert [f.name for f in dataclasses.fields(ModelingParams)] == names
    assert list(ModelingParams().to_dict()) == names


def test_dataclass_fields_repeat_the_definition_exactly():
    """Name, order, annotated type and default of every field equal those of PARAMETERS."""
    hints = typing.get_type_hints(ModelingParams)
    fields = dataclasses.fields(ModelingParams)
    assert [(f.name, hints[f.name], f.default) for f in fields] == \
        [(p.name, p.type, p.default) for p in PARAMETERS]
    for f, spec in zip(fields, PARAMETERS):
        # 1 == 1.0 == True: the default must also have the parameter's exact type.
        assert type(f.default) is spec.type, f.name
        assert f.kw_only and f.init, f.name


def test_constructor_rejects_positional_arguments():
    with pytest.raises(ParameterError, match="parameters are keyword-only; known: .*voxel_size"):
        ModelingParams(0.003)  # type: ignore[misc]


def test_params_survive_pickle_and_replace():
    p = ModelingParams(voxel_size=0.004, seed=3)
    assert pickle.loads(pickle.dumps(p)) == p
    assert dataclasses.replace(p, seed=4).seed == 4
    with pytest.raises(ParameterError, match="seed"):
        dataclasses.replace(p, seed=-1)


def test_every_numeric_parameter_has_a_range_unit_and_description():
    for spec in PARAMETERS:
        assert spec.description.strip(), spec.name
        if spec.type is bool:
            assert spec.low is None and spec.high is None
            continue
        if spec.type is str:
            # A choice: no range or unit; its default is one of its choices.
            assert spec.low is None and spec.high is None and spec.default in spec.choices
            continue
        assert spec.unit, spec.name
        assert spec.low is not None and spec.high is not None, spec.name
        assert spec.low <= spec.default <= spec.high, spec.name


def test_default_params_are_consistent():
    p = ModelingParams()
    assert p.min_radius < p.max_radius
    assert p.developable_curvature_ratio < p.sphere_curvature_ratio
    p.check_consistency()  # does not raise


def test_params_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        ModelingParams().voxel_size = 0.01  # type: ignore[misc]


# ---------------------------------------------------------------------------------------
# ParamSpec.check: one value against one definition
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(("name", "value", "match"), [
    ("voxel_size", -1.0, r"'voxel_size' = -1\.0 is outside the allowed range \[0\.0002, 0\.2\] m"),
    ("voxel_size", 0.5, r"'voxel_size' = 0\.5 is outside the allowed range \[0\.0002, 0\.2\] m"),
    ("normal_neighbors", 4, r"'normal_neighbors' = 4 is outside the allowed range \[5, 100\]"),
    ("cf_threshold", 1.5, r"'cf_threshold' = 1\.5 is outside the allowed range \[0\.0, 1\.0\]"),
    ("voxel_size", "0.003", r"'voxel_size' must be a float, got '0\.003'"),
    ("voxel_size", True, r"'voxel_size' must be a float, got True"),
    ("voxel_size", None, r"'voxel_size' must be a float, got None"),
    ("voxel_size", math.nan, r"'voxel_size' must be finite, got nan"),
    ("voxel_size", math.inf, r"'voxel_size' must be finite, got inf"),
    ("normal_neighbors", 16.5, r"'normal_neighbors' must be an integer, got 16\.5"),
    ("normal_neighbors", False, r"'normal_neighbors' must be a int, got False"),
    ("edge_correction", 1, r"'edge_correction' must be a bool, got 1"),
    ("edge_correction", "true", r"'edge_correction' must be a bool, got 'true'"),
])
def test_spec_check_rejects(name, value, match):
    with pytest.raises(ParameterError, match=match):
        SPECS[name].check(value)


def test_spec_check_converts_numbers():
    v = SPECS["ransac_max_iterations"].check(100.0)
    assert v == 100 and type(v) is int
    v = SPECS["max_radius"].check(3)
    assert v == 3.0 and type(v) is float
    assert SPECS["edge_correction"].check(False) is False


def test_parameter_error_is_a_value_error():
    assert issubclass(ParameterError, ValueError)


# ---------------------------------------------------------------------------------------
# ModelingParams construction
# ---------------------------------------------------------------------------------------


def test_valid_values_are_accepted():
    p = ModelingParams(voxel_size=0.004, normal_neighbors=20, edge_correction=False)
    assert (p.voxel_size, p.normal_neighbors, p.edge_correction) == (0.004, 20, False)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"voxel_size": -1.0}, r"voxel_size.*outside the allowed range \[0\.0002, 0\.2\] m"),
    ({"ransac_threshold": 0.0}, r"ransac_threshold.*outside the allowed range \[1e-06, 0\.5\] m"),
    ({"voxel_size": "0.003"}, r"'voxel_size' must be a float"),
    ({"voxel_size": True}, r"'voxel_size' must be a float"),
    ({"noise_amplitude": math.nan}, r"'noise_amplitude' must be finite"),
    ({"normal_neighbors": 3.5}, r"'normal_neighbors' must be an integer"),
    ({"edge_correction": "yes"}, r"'edge_correction' must be a bool"),
    ({"min_radius": 3.0, "max_radius": 2.0},
     r"min_radius \(3\.0\) must be smaller than max_radius \(2\.0\)"),
    ({"min_radius": 0.5, "max_radius": 0.5},
     r"min_radius \(0\.5\) must be smaller than max_radius \(0\.5\)"),
    ({"developable_curvature_ratio": 0.5}, r"developable_curvature_ratio must be smaller"),
])
def test_constructor_rejects_invalid_values(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        ModelingParams(**kwargs)


def test_constructor_rejects_unknown_name():
    with pytest.raises(ParameterError, match="bogus"):
        ModelingParams(bogus=1)  # type: ignore[call-arg]


def test_constructor_converts_to_the_parameter_type():
    p = ModelingParams(ransac_max_iterations=100.0, max_radius=3)
    assert type(p.ransac_max_iterations) is int
    assert type(p.max_radius) is float


def test_from_mapping_rejects_unknown_names():
    with pytest.raises(ParameterError,
                       match=r"unknown parameter\(s\) bogus, vox; known: .*voxel_size"):
        ModelingParams.from_mapping({"vox": 0.1, "bogus": 1})


@pytest.mark.parametrize(("values", "match"), [
    ({"voxel_size": -1}, r"voxel_size.*\[0\.0002, 0\.2\]"),
    ({"seed": -5}, r"seed.*\[0, 2147483647\]"),
    ({"min_radius": 2.5}, r"min_radius \(2\.5\) must be smaller than max_radius \(2\.0\)"),
])
def test_from_mapping_rejects_invalid_values(values, match):
    with pytest.raises(ParameterError, match=match):
        ModelingParams.from_mapping(values)


def test_from_mapping_keeps_base_values():
    base = ModelingParams(voxel_size=0.005, seed=7)
    p = ModelingParams.from_mapping({"seed": 3}, base=base)
    assert (p.voxel_size, p.seed) == (0.005, 3)
    assert ModelingParams.from_mapping({}) == ModelingParams()


# ---------------------------------------------------------------------------------------
# YAML files
# ---------------------------------------------------------------------------------------


def test_load_flat_yaml(tmp_path):
    f = tmp_path / "flat.yaml"
    f.write_text("voxel_size: 0.004\nnormal_neighbors: 20\nedge_correction: false\n")
    p = load_params_file(f)
    assert (p.voxel_size, p.normal_neighbors, p.edge_correction) == (0.004, 20, False)
    assert p.ransac_threshold == SPECS["ransac_threshold"].default


@pytest.mark.parametrize("node", ["modeler", "/**", "geomodel_modeler"])
def test_load_ros_params_layout(tmp_path, node):
    f = tmp_path / "ros.yaml"
    f.write_text(f"'{node}':\n  ros__parameters:\n    ransac_threshold: 0.004\n    seed: 9\n")
    p = load_params_file(f)
    assert (p.ransac_threshold, p.seed) == (0.004, 9)
    assert p.voxel_size == SPECS["voxel_size"].default


def test_load_empty_yaml_gives_defaults(tmp_path):
    f = tmp_path / "empty.yaml"
    f.write_text("")
    assert load_params_file(f) == ModelingParams()
    f.write_text("modeler:\n  ros__parameters:\n")
    assert load_params_file(f) == ModelingParams()


def test_load_yaml_with_unknown_name(tmp_path):
    f = tmp_path / "typo.yaml"
    f.write_text("modeler:\n  ros__parameters:\n    voxelsize: 0.004\n")
    with pytest.raises(ParameterError, match=r"unknown parameter\(s\) voxelsize"):
        load_params_file(f)


def test_load_yaml_with_out_of_range_value(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("voxel_size: -0.004\n")
    with pytest.raises(ParameterError, match=r"voxel_size.*\[0\.0002, 0\.2\]"):
        load_params_file(f)


def test_load_missing_yaml(tmp_path):
    with pytest.raises(ParameterError, match=r"cannot read parameter file .*missing\.yaml"):
        load_params_file(tmp_path / "missing.yaml")


def test_load_invalid_yaml(tmp_path):
    f = tmp_path / "broken.yaml"
    f.write_text("voxel_size: [0.1\n")
    with pytest.raises(ParameterError, match=r"broken\.yaml is not valid YAML"):
        load_params_file(f)


def test_load_yaml_that_is_not_a_mapping(tmp_path):
    f = tmp_path / "list.yaml"
    f.write_text("- 1\n- 2\n")
    with pytest.raises(ParameterError, match=r"must hold a mapping, got list"):
        load_params_file(f)


def test_config_modeler_yaml_is_generated_from_the_definitions():
    assert (CONFIG / "modeler.yaml").read_text() == params_yaml()


def test_config_modeler_yaml_loads_to_the_defaults():
    assert load_params_file(CONFIG / "modeler.yaml") == ModelingParams()


def test_params_yaml_lists_every_parameter_with_its_range():
    text = params_yaml()
    for spec in PARAMETERS:
        assert f"\n    {spec.name}: " in text
        if spec.low is not None:
            assert f"[{spec.low}, {spec.high}]" in text


def test_sensor_noise_yaml_loads():
    p = load_params_file(CONFIG / "sensor_noise.yaml")
    assert (p.noise_amplitude, p.ransac_threshold, p.voxel_size) == (0.001, 0.004, 0.004)
