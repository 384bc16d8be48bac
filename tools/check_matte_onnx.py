"""Compare the converted person matte (ONNX) with MediaPipe's own TFLite pipeline on real photos.

Run in the scratch environment that has mediapipe 0.10.21 and onnxruntime
(tools/convert_selfie_matte.py says how to make it); not run by CI:

    /tmp/mattevenv/bin/python tools/check_matte_onnx.py relight/models/person_matte.onnx \\
        relight/data/matte_eval/*.jpg relight/data/matte_eval/*.png [--landscape]

Each photo is resized to the model's input size first, so MediaPipe's own
resize to the model input is the identity and both sides see the same
pixels (the TFLite interpreter alone cannot run the graph: it lacks
MediaPipe's custom op Convolution2DTransposeBias). Prints the largest
absolute difference of the two masks per photo and over all.
"""

import sys

import numpy as np
from PIL import Image


def main(argv) -> int:
    import mediapipe as mp
    import onnxruntime as ort

    landscape = "--landscape" in argv
    paths = [a for a in argv if a != "--landscape"]
    model, photos = paths[0], paths[1:]
    session = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    _, _, h, w = session.get_inputs()[0].shape
    seg = mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=1 if landscape else 0)
    worst = 0.0
    for path in photos:
        rgb = np.asarray(Image.open(path).convert("RGB").resize((w, h), Image.Resampling.BILINEAR))
        ref = seg.process(np.ascontiguousarray(rgb)).segmentation_mask
        x = (rgb.astype(np.float32) / 255.0).transpose(2, 0, 1)[None]
        got = session.run(["mask"], {"image": x})[0][0, 0]
        diff = float(np.abs(got - ref).max())
        worst = max(worst, diff)
        print(f"{path}: max |onnx - mediapipe| = {diff:.2e}")
    print(f"all photos: max abs difference {worst:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
