"""The encoder runtime policy (hypergs_blender/runtime.py), without Blender: which onnxruntime execution
providers a device choice asks for, the HYPERGS_ENCODER choice, the session's encoder cache and how
what encoded is described. (The add-on preferences that make the Runtime: test_blender_addon.py.)"""
import shutil

import pytest

from hypergs_blender import optional, runtime
from hypergs_blender.errors import HyperGSError
from hypergs_blender.network import WEIGHTS_DIR
from hypergs_blender.runtime import AUTO, PROVIDERS, Runtime, describe_encoder, make_encoder, providers_for

CUDA, DML, COREML, CPU = PROVIDERS


def test_providers_for_a_device_choice():
    assert providers_for(AUTO, [CUDA, CPU]) == [CUDA, CPU]
    assert providers_for(DML, [CUDA, CPU]) == [CPU]  # asked for what this onnxruntime lacks: the CPU
    assert providers_for(CPU, [COREML, CPU]) == [CPU]
    assert providers_for(AUTO, [COREML, CPU]) == [COREML, CPU]
    assert providers_for(DML, [CUDA, DML, CPU]) == [DML, CPU]
    assert providers_for(AUTO, []) == [CPU]


def test_available_providers_are_the_known_ones_best_first():
    available = runtime.available_providers()
    assert CPU in available and available[-1] == CPU
    assert available == [p for p in PROVIDERS if p in available]


@pytest.fixture
def session_cache(monkeypatch):
    monkeypatch.setattr(runtime, "_cache", {})
    return runtime._cache


def test_the_environment_picks_the_floor_and_refuses_other_names(monkeypatch, session_cache):
    monkeypatch.setenv("HYPERGS_ENCODER", "floor")
    floor = make_encoder()
    assert floor.name == "floor" and describe_encoder(floor, Runtime()) == "floor"
    assert make_encoder(Runtime(CPU, 2)) is floor  # the floor does not depend on the runtime
    monkeypatch.setenv("HYPERGS_ENCODER", "magic")
    with pytest.raises(HyperGSError, match="HYPERGS_ENCODER='magic'"):
        make_encoder()


@pytest.mark.filterwarnings("ignore:Specified provider 'CUDAExecutionProvider' is not in available provider names")
def test_the_bundled_network_runs_where_asked_and_is_loaded_once(monkeypatch, session_cache):
    monkeypatch.setattr(optional, "torch_available", lambda: False)  # as in Blender's Python: onnxruntime
    monkeypatch.delenv("HYPERGS_ENCODER", raising=False)
    asked = Runtime(CUDA, 1)  # not in the CPU onnxruntime here: the CPU runs it, with the threads asked for
    encoder = make_encoder(asked)
    assert encoder.name == "network-onnx" and encoder.provider == CPU
    assert encoder.session.get_session_options().intra_op_num_threads == 1
    assert describe_encoder(encoder, asked) == "network-onnx on CPU (1 thread)"
    assert describe_encoder(encoder, Runtime()) == "network-onnx on CPU (all cores)"
    assert describe_encoder(encoder, Runtime(CPU, 4)) == "network-onnx on CPU (4 threads)"
    assert make_encoder(asked) is encoder and len(session_cache) == 1
    other = make_encoder(Runtime(CPU, 2))  # another runtime: loaded again, one network in memory
    assert other is not encoder and len(session_cache) == 1


@pytest.fixture(scope="module")
def transformer_folder(tmp_path_factory):
    from tiny_transformer import export_tiny_transformer
    return export_tiny_transformer(tmp_path_factory.mktemp("transformer")).parent


def test_the_transformer_loads_from_the_folder_set_and_only_from_a_transformer(transformer_folder, tmp_path,
                                                                               monkeypatch, session_cache):
    monkeypatch.setattr(optional, "torch_available", lambda: False)  # as in Blender's Python: onnxruntime
    monkeypatch.delenv("HYPERGS_ENCODER", raising=False)
    monkeypatch.setattr(runtime, "WEIGHTS_DIR", tmp_path / "bundles_none")
    assert not runtime.transformer_available(Runtime())
    with pytest.raises(HyperGSError, match="bundles none; train and export one"):
        make_encoder(Runtime(), "transformer")
    chosen = Runtime(CPU, 1, str(transformer_folder))
    assert runtime.transformer_available(chosen)
    assert runtime.model_weights(chosen, "transformer") == transformer_folder / "hypergs_transformer.json"
    encoder = make_encoder(chosen, "transformer")
    assert encoder.name == "transformer-onnx" and describe_encoder(encoder, chosen) == "transformer-onnx on CPU (1 thread)"
    assert make_encoder(chosen, "transformer") is encoder and len(session_cache) == 1
    assert make_encoder(chosen, "conv").name == "network-onnx" and len(session_cache) == 1  # one network in memory
    (tmp_path / "conv").mkdir()
    shutil.copy(WEIGHTS_DIR / "hypergs.json", tmp_path / "conv")
    conv = Runtime(transformer_weights=str(tmp_path / "conv"))  # a folder of the conv network alone
    assert not runtime.transformer_available(conv)
    with pytest.raises(HyperGSError, match="holds the conv network's weights, not a transformer's"):
        make_encoder(conv, "transformer")
    (tmp_path / "broken.json").write_text("{not json")
    with pytest.raises(HyperGSError, match="not a model's card"):
        runtime.model_weights(Runtime(transformer_weights=str(tmp_path / "broken.json")), "transformer")
    with pytest.raises(HyperGSError, match="unknown model 'vit'"):
        make_encoder(chosen, "vit")


def test_the_bundled_transformer_is_offered_without_a_folder(monkeypatch):
    monkeypatch.delenv("HYPERGS_ENCODER", raising=False)
    assert runtime.model_weights(Runtime(), "transformer") == WEIGHTS_DIR / "hypergs_transformer.json"
    assert runtime.transformer_available(Runtime()) and runtime.model_weights(Runtime(), "conv") is None
