"""The Sparkplug 3.0 TCK's edge-node ids (tck_edge_ids.tsv), the decorator by which a test of
edge_node_test.py names the ids it checks, and the ids that do not apply to ioportd, with why.
docs/sparkplug-conformance.md is generated from these, host_app.RULES and the decorators
(conformance.py), and checked against them in CTest."""
import os

TSV = os.path.join(os.path.dirname(os.path.abspath(__file__)), "tck_edge_ids.tsv")


def load_ids(path=TSV):
    """id -> {"classes": [TCK class, …], "section": §, "text": the specification's words}."""
    ids = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            test_class, id_, section, text = line.rstrip("\n").split("\t")
            entry = ids.setdefault(id_, {"classes": [], "section": section, "text": text})
            entry["classes"].append(test_class)
    return ids


IDS = load_ids()


def covers(*ids):
    """Marks a test as checking these TCK ids (or a gateway.md section): a typo fails at import."""
    unknown = [i for i in ids if i not in IDS and not i.startswith("gateway.md")]
    if unknown:
        raise ValueError(f"not Sparkplug 3.0 TCK edge ids: {unknown}")

    def mark(test):
        test.tck_ids = ids
        return test
    return mark


_PARAMETERS = ("ioportd's templates have no parameters (gateway.md §7.2: a module type's members "
               "are its §5.5 metrics)")
_DATASETS = "ioportd publishes no DataSet"
_QUALITY = "ioportd sends no quality property (its metrics' properties are gateway.md §6.1's)"

NOT_APPLICABLE = {
    **{i: _PARAMETERS for i in IDS if "-template-parameter-" in i},
    "tck-id-payloads-template-definition-parameters-default": _PARAMETERS,
    "tck-id-payloads-template-instance-parameters": _PARAMETERS,
    "tck-id-payloads-template-dataset-value": _DATASETS,
    **{i: _DATASETS for i in IDS if "-dataset-" in i and "template" not in i},
    **{i: _QUALITY for i in IDS if "propertyset-quality" in i},
}
