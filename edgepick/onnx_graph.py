"""An ONNX graph read and edited through one object, `Graph`: which node makes a tensor and which
nodes read it, node attributes, initializers and Constant values as numpy arrays, and edits
(remove, replace, insert, redirect) after which those answers stay true. Every ONNX pass of
edgepick's (export's int8 passes, quant's rewrites and measurements) works through it.

onnx is imported inside the functions: this module imports on the torch-free base install, which
has no onnx."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import onnx


def attr(node: onnx.NodeProto, name: str, default: Any = None) -> Any:
    """NODE's attribute NAME as a Python value (ints, floats, bytes, lists, tensors), or DEFAULT."""
    from onnx import helper

    return next((helper.get_attribute_value(a) for a in node.attribute if a.name == name), default)


def attrs(node: onnx.NodeProto) -> dict[str, Any]:
    """All of NODE's attributes as Python values, by name."""
    from onnx import helper

    return {a.name: helper.get_attribute_value(a) for a in node.attribute}


def copy_model(model: onnx.ModelProto) -> onnx.ModelProto:
    """A deep copy of MODEL (a pass that measures a variant leaves the original as it was)."""
    import onnx

    copy = onnx.ModelProto()
    copy.CopyFrom(model)
    return copy


class Graph:
    """The graph of an onnx ModelProto, edited in place. The producer and consumer maps are built
    when first asked for and again after an edit made through this object; an edit made to the
    protos directly is not seen until `changed()` is called."""

    def __init__(self, model: onnx.ModelProto):
        self.model = model
        self.graph = model.graph
        self._producer: dict[str, onnx.NodeProto] | None = None
        self._consumers: dict[str, list[onnx.NodeProto]] = {}
        self._inits: dict[str, onnx.TensorProto] | None = None

    # reading

    @property
    def nodes(self) -> list[onnx.NodeProto]:
        """The nodes, in graph order (a list: edits during a walk over it do not move the walk)."""
        return list(self.graph.node)

    @property
    def outputs(self) -> set[str]:
        """The graph's output names."""
        return {o.name for o in self.graph.output}

    @property
    def inputs(self) -> list[str]:
        """The graph's real inputs (older files also list their initializers as inputs)."""
        return [i.name for i in self.graph.input if not self.is_initializer(i.name)]

    def producer(self, tensor: str) -> onnx.NodeProto | None:
        """The node that makes TENSOR (None for a graph input, an initializer or an unknown name)."""
        return self._links()[0].get(tensor)

    def consumers(self, tensor: str) -> list[onnx.NodeProto]:
        """The nodes that read TENSOR, in graph order (a node reading it twice is listed twice)."""
        return self._links()[1].get(tensor, [])

    def only_consumer(self, tensor: str, op_type: str | None = None) -> onnx.NodeProto | None:
        """The one node that reads TENSOR (of OP_TYPE, when given), if TENSOR is no graph output."""
        users = self.consumers(tensor)
        if tensor in self.outputs or len(users) != 1 or (op_type is not None and users[0].op_type != op_type):
            return None
        return users[0]

    def node(self, name: str) -> onnx.NodeProto | None:
        """The node called NAME."""
        return next((n for n in self.graph.node if n.name == name), None)

    def index(self, node: onnx.NodeProto) -> int:
        """NODE's place in the graph's node list."""
        return next(k for k, n in enumerate(self.graph.node) if n is node)

    # initializers and constants

    def initializer(self, name: str) -> onnx.TensorProto | None:
        if self._inits is None:
            self._inits = {i.name: i for i in self.graph.initializer}
        return self._inits.get(name)

    def is_initializer(self, name: str) -> bool:
        return self.initializer(name) is not None

    def array(self, name: str, through: Sequence[str] = ()) -> np.ndarray | None:
        """The value of the initializer NAME, or of the Constant node that makes NAME, as a new numpy
        array; with THROUGH (op types such as Cast, Identity), also of a constant passed through them.
        None when NAME is no constant."""
        from onnx import numpy_helper

        init = self.initializer(name)
        if init is not None:
            return numpy_helper.to_array(init)
        node = self.producer(name)
        if node is None:
            return None
        if node.op_type == "Constant" and node.attribute and node.attribute[0].name == "value":
            return numpy_helper.to_array(node.attribute[0].t)
        if node.op_type in through and node.input:
            return self.array(node.input[0], through)
        return None

    def is_constant(self, name: str, through: Sequence[str] = ()) -> bool:
        """Whether NAME is an initializer or a Constant's output (passed through THROUGH's op types)."""
        if self.is_initializer(name):
            return True
        node = self.producer(name)
        if node is None:
            return False
        if node.op_type == "Constant":
            return bool(node.attribute) and node.attribute[0].name == "value"
        return node.op_type in through and bool(node.input) and self.is_constant(node.input[0], through)

    def scalar(self, name: str, through: Sequence[str] = ()) -> float | None:
        """The constant NAME's value when it holds exactly one, else None."""
        value = self.array(name, through) if name else None
        return float(value.ravel()[0]) if value is not None and value.size == 1 else None

    def set_array(self, name: str, value: np.ndarray) -> None:
        """The initializer NAME takes VALUE (its dtype and shape too); added when there is none."""
        from onnx import numpy_helper

        tensor = numpy_helper.from_array(np.asarray(value), name)
        init = self.initializer(name)
        if init is None:
            self.add_tensor(tensor)
        else:
            init.CopyFrom(tensor)

    def add_initializer(self, name: str, value: Any, dtype: Any = None) -> str:
        """A new initializer NAME holding VALUE (as DTYPE when given); returns NAME."""
        from onnx import numpy_helper

        self.add_tensor(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def add_tensor(self, tensor: onnx.TensorProto) -> None:
        """TENSOR (a TensorProto, copied in) as a new initializer."""
        self.graph.initializer.append(tensor)
        self._inits = None

    def remove_initializers(self, names: Iterable[str]) -> None:
        """Drop the initializers NAMES and their graph-input entries."""
        names = set(names)
        keep = [i for i in self.graph.initializer if i.name not in names]
        if len(keep) != len(self.graph.initializer):
            del self.graph.initializer[:]
            self.graph.initializer.extend(keep)
        inputs = [v for v in self.graph.input if v.name not in names]
        if len(inputs) != len(self.graph.input):
            del self.graph.input[:]
            self.graph.input.extend(inputs)
        self._inits = None

    def read_names(self) -> set[str]:
        """Every tensor name a node (or a node of a subgraph) reads, and the graph outputs."""
        used = {name for node in self.graph.node for name in node.input}
        used |= {name for node in self.graph.node for a in node.attribute if a.g.node
                 for sub in a.g.node for name in sub.input}
        return used | self.outputs

    def drop_unused_initializers(self) -> int:
        """Remove the initializers nothing reads, and their graph-input entries (onnxruntime warns
        about each one on every load). Returns how many went."""
        used = self.read_names()
        unused = [i.name for i in self.graph.initializer if i.name not in used]
        self.remove_initializers(unused)
        return len(unused)

    # editing

    def changed(self) -> None:
        """Forget the maps: the next question builds them from the protos again."""
        self._producer, self._inits = None, None

    def remove(self, *nodes: onnx.NodeProto) -> None:
        """Take NODES out of the graph."""
        gone = {id(n) for n in nodes}
        for k in reversed([k for k, n in enumerate(self.graph.node) if id(n) in gone]):
            del self.graph.node[k]
        self.changed()

    def insert(self, at: int, nodes: Sequence[onnx.NodeProto]) -> None:
        """Put copies of NODES, in order, at place AT of the node list."""
        for k, node in enumerate(nodes):
            self.graph.node.insert(at + k, node)
        self.changed()

    def insert_before(self, anchor: onnx.NodeProto, nodes: Sequence[onnx.NodeProto]) -> None:
        self.insert(self.index(anchor), nodes)

    def insert_after(self, anchor: onnx.NodeProto, nodes: Sequence[onnx.NodeProto]) -> None:
        self.insert(self.index(anchor) + 1, nodes)

    def append(self, nodes: Sequence[onnx.NodeProto]) -> None:
        """Put copies of NODES at the end of the node list."""
        self.graph.node.extend(nodes)
        self.changed()

    def replace(self, old: onnx.NodeProto | Sequence[onnx.NodeProto], new: Sequence[onnx.NodeProto],
                at: onnx.NodeProto | None = None) -> None:
        """Put NEW where AT is (by default the first of OLD), then take OLD (one node or several) out."""
        old = [old] if not isinstance(old, Sequence) else list(old)
        self.insert(self.index(at if at is not None else old[0]), new)
        self.remove(*old)

    def set_input(self, node: onnx.NodeProto, k: int, name: str) -> None:
        """NODE's input K reads NAME."""
        node.input[k] = name
        self.changed()

    def set_inputs(self, node: onnx.NodeProto, names: Sequence[str]) -> None:
        """NODE's inputs become NAMES."""
        del node.input[:]
        node.input.extend(names)
        self.changed()

    def set_output(self, node: onnx.NodeProto, old: str, new: str) -> None:
        """NODE writes NEW where it wrote OLD."""
        node.output[list(node.output).index(old)] = new
        self.changed()

    def redirect(self, old: str, new: str) -> None:
        """Every node that reads OLD reads NEW instead."""
        for user in self.consumers(old):
            for k, name in enumerate(user.input):
                if name == old:
                    user.input[k] = new
        self.changed()

    def set_nodes(self, nodes: Sequence[onnx.NodeProto]) -> None:
        """The node list becomes copies of NODES, in that order (a reordering, or a new list)."""
        import onnx

        copies = [onnx.NodeProto() for _ in nodes]
        for copy, node in zip(copies, nodes):
            copy.CopyFrom(node)
        del self.graph.node[:]
        self.graph.node.extend(copies)
        self.changed()

    def insert_after_producers(self, after: dict[str, list[onnx.NodeProto]]) -> None:
        """Put the nodes AFTER[tensor] right after the node that makes the tensor (at the end for a
        graph input): onnxruntime's priority order runs nodes as given, so a node that reduces a
        feature map runs as soon as the map is made and the map is freed as early as without it."""
        pending = dict(after)
        ordered = []
        for node in self.graph.node:
            ordered.append(node)
            ordered.extend(n for o in node.output for n in pending.pop(o, []))
        ordered.extend(n for nodes in pending.values() for n in nodes)
        self.set_nodes(ordered)

    def sort(self) -> None:
        """Order the nodes so that each comes after the nodes whose outputs it reads (a cycle or a
        missing input: the rest stays as it was, at the end)."""
        known = {i.name for i in self.graph.input} | {i.name for i in self.graph.initializer} | {""}
        ordered, pending = [], list(self.graph.node)
        while pending:
            ready = [k for k, n in enumerate(pending) if all(i in known for i in n.input)]
            if not ready:
                ordered.extend(pending)
                break
            for k in ready:
                known.update(pending[k].output)
            ordered.extend(pending[k] for k in ready)
            taken = set(ready)
            pending = [n for k, n in enumerate(pending) if k not in taken]
        self.set_nodes(ordered)

    def name_nodes(self) -> int:
        """Give every node without a name a unique one (its op type and place). Returns how many."""
        taken = {n.name for n in self.graph.node}
        named = 0
        for k, node in enumerate(self.graph.node):
            if not node.name:
                name = f"{node.op_type}_{k}"
                while name in taken:
                    name += "_"
                node.name = name
                taken.add(name)
                named += 1
        return named

    def _links(self) -> tuple[dict[str, onnx.NodeProto], dict[str, list[onnx.NodeProto]]]:
        if self._producer is None:
            self._producer = {o: n for n in self.graph.node for o in n.output}
            self._consumers = {}
            for n in self.graph.node:
                for i in n.input:
                    self._consumers.setdefault(i, []).append(n)
        return self._producer, self._consumers
