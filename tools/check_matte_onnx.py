"""Compare the converted person-matte networks (ONNX) with the TFLite originals on real photos.

Not run by CI. Each photo is resized to the network's input, the same pixels
go to both sides, and the largest absolute difference of the outputs is
printed per photo and over all.

    # selfie segmentation: against MediaPipe's own pipeline (the plain TFLite
    # interpreter cannot run it: it lacks MediaPipe's custom op
    # Convolution2DTransposeBias); photos resized to 256 x 256 so that
    # MediaPipe's resize is the identity. Scratch env with mediapipe 0.10.21:
    /tmp/mattevenv/bin/python tools/check_matte_onnx.py mediapipe \\
        relight/models/person_matte_selfie.onnx evaluation/data/matte_eval/*.jpg evaluation/data/matte_eval/*.png

    # pose detector and pose segmentation: against the TFLite interpreter's
    # reference kernels (ai-edge-litert; XNNPACK, MediaPipe's default, differs
    # from both by more on the segmentation logits). Scratch env with
    # ai-edge-litert, onnxruntime, Pillow:
    /tmp/convvenv/bin/python tools/check_matte_onnx.py litert MP/pose_detection/pose_detection.tflite \\
        relight/models/person_matte_pose_detector.onnx PHOTOS...
    /tmp/convvenv/bin/python tools/check_matte_onnx.py litert MP/pose_landmark/pose_landmark_full.tflite \\
        relight/models/person_matte_pose_segmentation.onnx PHOTOS...

    # issue 37's face landmark network (relight/models/face_landmark.onnx at commit 6d8d254), the same
    # way, on the photos' face crops (3.1e-05 input pixels)

(MP: the mediapipe/modules folder of the unpacked mediapipe 0.10.21 wheel.)
The pose segmentation is compared as probabilities (sigmoid of the TFLite
logits), the detector's box regressors in pixels of its 224 x 224 input and
its score logits.
"""

import sys

import numpy as np
from PIL import Image


def _rgb(path, w, h) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB").resize((w, h), Image.Resampling.BILINEAR))


def against_mediapipe(model: str, photos: list[str]) -> float:
    import mediapipe as mp
    import onnxruntime as ort

    session = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    _, _, h, w = session.get_inputs()[0].shape
    seg = mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=0 if h == w else 1)
    worst = 0.0
    for path in photos:
        rgb = _rgb(path, w, h)
        ref = seg.process(np.ascontiguousarray(rgb)).segmentation_mask
        got = session.run(["mask"], {"image": (rgb.astype(np.float32) / 255.0).transpose(2, 0, 1)[None]})[0][0, 0]
        diff = float(np.abs(got - ref).max())
        worst = max(worst, diff)
        print(f"{path}: max |onnx - mediapipe| = {diff:.2e}")
    return worst


def against_litert(tflite: str, model: str, photos: list[str]) -> float:
    import onnxruntime as ort
    from ai_edge_litert.interpreter import Interpreter, OpResolverType

    interpreter = Interpreter(model_path=tflite,
                              experimental_op_resolver_type=OpResolverType.BUILTIN_WITHOUT_DEFAULT_DELEGATES)
    interpreter.allocate_tensors()
    (inp,) = interpreter.get_input_details()
    by_name = {d["name"]: d for d in interpreter.get_output_details()}
    session = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    outputs = [o.name for o in session.get_outputs()]
    _, h, w, _ = inp["shape"]
    detector = outputs == ["boxes", "scores"]
    face = {"landmarks": "conv2d_21", "face_flag": "conv2d_31"} if outputs == ["landmarks", "face_flag"] else (
        {"boxes": "regressors", "scores": "classificators"} if detector and "regressors" in by_name else None)
    worst = 0.0
    for path in photos:
        x = _rgb(path, w, h).astype(np.float32) / 255.0
        interpreter.set_tensor(inp["index"], (x * 2 - 1 if detector else x)[None])
        interpreter.invoke()
        got = session.run(outputs, {"image": x.transpose(2, 0, 1)[None]})
        if face is not None:  # a face landmark network: landmarks in input pixels, the face flag a probability
            refs = [interpreter.get_tensor(by_name[face[n]]["index"]).astype(np.float64) for n in outputs]
            if "face_flag" in outputs:
                refs[1] = 1.0 / (1.0 + np.exp(-np.clip(refs[1], -80, 80)))
            refs = [r.reshape(g.shape) for r, g in zip(refs, got)]
        elif detector:
            refs = [interpreter.get_tensor(by_name[n]["index"]) for n in ("Identity", "Identity_1")]
        else:
            logits = interpreter.get_tensor(by_name["Identity_2"]["index"]).astype(np.float64)
            refs = [(1.0 / (1.0 + np.exp(-np.clip(logits, -80, 80)))).transpose(0, 3, 1, 2)]
            if "landmarks" in outputs:  # the landmark regressors, in pixels of the 256 x 256 input
                refs.append(interpreter.get_tensor(by_name["Identity"]["index"]))
        diffs = [float(np.abs(g - r).max()) for g, r in zip(got, refs)]
        worst = max(worst, *diffs)
        print(f"{path}: max |onnx - tflite| = " + ", ".join(f"{n} {d:.2e}" for n, d in zip(outputs, diffs)))
    return worst


def main(argv) -> int:
    if argv[:1] == ["mediapipe"]:
        worst = against_mediapipe(argv[1], argv[2:])
    elif argv[:1] == ["litert"]:
        worst = against_litert(argv[1], argv[2], argv[3:])
    else:
        print(__doc__)
        return 2
    print(f"all photos: max abs difference {worst:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
