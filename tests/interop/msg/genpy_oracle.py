"""Oracle run under Debian's /usr/bin/python3: answers with what genmsg/genpy compute, as JSON on stdout.

Commands (argv[1]):
  md5     -- md5sum and full text (genpy's _full_text) of every .msg/.srv under /usr/share/*/{msg,srv}
  reencode -- stdin: JSON list of [type, hex bytes]; genpy deserializes and serializes each, answers hex
  classes  -- _md5sum, _full_text and _has_header of every importable genpy message class
  sample   -- stdin: JSON list of types; answers [type, hex] of genpy messages filled with varied values

Not a test module: tests call it with the system interpreter (which has genmsg, genpy and the msg packages).
"""

import glob
import importlib
import json
import os
import random
import sys


def md5_table():
    import genmsg
    import genmsg.gentools
    import genmsg.msg_loader

    search = {}
    for kind in ("msg", "srv"):
        for directory in glob.glob(f"/usr/share/*/{kind}"):
            search.setdefault(directory.split("/")[3], []).append(directory)
    out = {}
    for path in sorted(glob.glob("/usr/share/*/msg/*.msg") + glob.glob("/usr/share/*/srv/*.srv")):
        parts = path.split("/")
        pkg, kind, name = parts[3], parts[4], os.path.splitext(parts[5])[0]
        full = f"{pkg}/{name}"
        context = genmsg.msg_loader.MsgContext.create_default()
        try:
            if kind == "msg":
                spec = genmsg.msg_loader.load_msg_from_file(context, path, full)
                genmsg.msg_loader.load_depends(context, spec, search)
                md5 = genmsg.gentools.compute_md5(context, spec)
                text = genmsg.gentools.compute_full_text(context, spec)
                out[f"msg:{full}"] = {"md5": md5, "full_text": text}
            else:
                spec = genmsg.msg_loader.load_srv_from_file(context, path, full)
                genmsg.msg_loader.load_depends(context, spec, search)
                out[f"srv:{full}"] = {
                    "md5": genmsg.gentools.compute_md5(context, spec),
                    "request_md5": genmsg.gentools.compute_md5(context, spec.request),
                    "response_md5": genmsg.gentools.compute_md5(context, spec.response),
                    "request_full_text": genmsg.gentools.compute_full_text(context, spec.request),
                    "response_full_text": genmsg.gentools.compute_full_text(context, spec.response),
                }
        except Exception as exc:
            out[f"{kind}:{full}"] = {"error": repr(exc)}
    return out


_DYNAMIC = {}


def message_class(name):
    """The installed genpy class, or one genpy generates from the /usr/share definition."""
    pkg, short = name.split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), short)
    except (ImportError, AttributeError):
        pass
    if name not in _DYNAMIC:
        import genmsg.gentools
        import genmsg.msg_loader
        import genpy.dynamic

        search = {}
        for directory in glob.glob("/usr/share/*/msg"):
            search.setdefault(directory.split("/")[3], []).append(directory)
        context = genmsg.msg_loader.MsgContext.create_default()
        spec = genmsg.msg_loader.load_msg_by_type(context, name, search)
        genmsg.msg_loader.load_depends(context, spec, search)
        text = genmsg.gentools.compute_full_text(context, spec)
        _DYNAMIC.update(genpy.dynamic.generate_dynamic(name, text))
    return _DYNAMIC[name]


def reencode(items):
    out = []
    for name, data in items:
        msg = message_class(name)()
        msg.deserialize(bytes.fromhex(data))
        from io import BytesIO

        buff = BytesIO()
        msg.serialize(buff)
        out.append(buff.getvalue().hex())
    return out


def random_value(base, rng):
    """One genpy value of element type ``base``."""
    import genpy

    if base in ("float32", "float64"):
        return rng.choice([0.0, 1.5, -2.25, 1e3, 0.125])
    if base == "bool":
        return rng.choice([True, False])
    if base in ("int8", "byte"):
        return rng.randint(-128, 127)
    if base in ("uint8", "char"):
        return rng.randint(0, 255)
    if base.startswith("int"):
        bits = int(base[3:])
        return rng.randint(-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
    if base.startswith("uint"):
        return rng.randint(0, 2 ** int(base[4:]) - 1)
    if base == "string":
        return rng.choice(["", "a", "héllo wörld", "日本語", "x" * 40])
    if base == "time":
        return genpy.Time(rng.randint(0, 2**32 - 1), rng.randint(0, 999999999))
    if base == "duration":
        return genpy.Duration(rng.randint(-(2**31), 2**31 - 1), rng.randint(0, 999999999))
    sub = message_class(base if "/" in base else "std_msgs/Header")()
    fill(sub, rng)
    return sub


def fill(msg, rng):
    """Set every field of a genpy message to varied values (arrays of 0, 1 or 3 items)."""
    for name, slot in zip(msg.__slots__, msg._slot_types, strict=True):
        base = slot.split("[")[0]
        if "[" not in slot:
            setattr(msg, name, random_value(base, rng))
            continue
        inner = slot[slot.index("[") + 1 : -1]
        count = int(inner) if inner else rng.choice([0, 1, 3])
        if base in ("uint8", "char"):
            setattr(msg, name, bytes(rng.randint(0, 255) for _ in range(count)))
        else:
            setattr(msg, name, [random_value(base, rng) for _ in range(count)])


def sample(names):
    """Three genpy messages per type, filled with seeded varied values, serialized by genpy."""
    from io import BytesIO

    rng = random.Random(1234)
    out = []
    for name in names:
        for _ in range(3):
            msg = message_class(name)()
            fill(msg, rng)
            buff = BytesIO()
            msg.serialize(buff)
            out.append([name, buff.getvalue().hex()])
    return out


def classes():
    out = {}
    for path in sorted(glob.glob("/usr/share/*/msg/*.msg")):
        parts = path.split("/")
        name = f"{parts[3]}/{os.path.splitext(parts[5])[0]}"
        try:
            cls = message_class(name)
        except (ImportError, AttributeError):
            continue
        out[name] = {"md5": cls._md5sum, "full_text": cls._full_text, "has_header": cls._has_header}
    return out


def main():
    command = sys.argv[1]
    if command == "md5":
        result = md5_table()
    elif command == "classes":
        result = classes()
    elif command == "reencode":
        result = reencode(json.load(sys.stdin))
    elif command == "sample":
        result = sample(json.load(sys.stdin))
    else:
        raise SystemExit(f"unknown command {command}")
    json.dump(result, sys.stdout)


if __name__ == "__main__":
    main()
