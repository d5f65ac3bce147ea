"""The simulated OPC UA server's standard address space: built once per process
and shared by each server until it looks a node up (`drivers.opcua_space`), the
same nodes as asyncua's own fill, and no server sees what another one changed."""

from __future__ import annotations

import asyncio

import pytest
from asyncua import ua
from asyncua.server.address_space import NodeData
from asyncua.server.server import Server
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.object_ids import ObjectIds

from drivers import opcua_space
from drivers.opcua_space import SharedNodes, standard_nodes
from drivers.sim.opcua_server import NAMESPACE, OpcUaSimController


def _node(name: str) -> ua.NodeId:
    """A standard node's id by its name in asyncua's ObjectIds."""
    return ua.NodeId.from_string(f"i={getattr(ObjectIds, name)}")


def count_builds(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Forget the process's template and count the builds from here on (an entry
    per build of the standard address space)."""
    builds: list[int] = []
    build = opcua_space._build

    def counting() -> dict[ua.NodeId, NodeData]:
        builds.append(1)
        return build()

    monkeypatch.setattr(opcua_space, "_template", None)
    monkeypatch.setattr(opcua_space, "_build", counting)
    return builds


async def test_the_standard_space_is_built_once_and_copied(
        monkeypatch: pytest.MonkeyPatch) -> None:
    builds = count_builds(monkeypatch)
    first, second = await standard_nodes(), await standard_nodes()
    assert len(builds) == 1
    assert first.keys() == second.keys()
    some = _node("Server_NamespaceArray")
    assert first[some] is not second[some]
    assert first[some].references is not second[some].references


async def test_servers_started_together_build_the_space_once(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A farm starts its servers at once: they wait for one build, not one each."""
    builds = count_builds(monkeypatch)
    spaces = await asyncio.gather(*(standard_nodes() for _ in range(4)))
    assert len(builds) == 1
    assert all(s.keys() == spaces[0].keys() for s in spaces)


async def test_a_server_shares_the_nodes_it_never_looked_up() -> None:
    """A started simulated controller and a client's browse copy about a hundred
    standard nodes; the thousands it never looked up stay the template's."""
    sim = OpcUaSimController()
    await sim.start()
    try:
        nodes = sim._require().iserver.aspace._nodes
        assert isinstance(nodes, SharedNodes)
        template = opcua_space._template
        assert template is not None
        status = _node("Server_ServerStatus")
        assert dict.__getitem__(nodes, status) is not template[status]
        untouched = _node("HistoricalDataConfigurationType")
        assert dict.__getitem__(nodes, untouched) is template[untouched]
        assert nodes.shared() > 0.9 * len(template)
        # a lookup by any route hands out the server's own copy
        mine = nodes[untouched]
        assert mine is not template[untouched] and nodes.get(untouched) is mine
        assert mine.attributes is not template[untouched].attributes
        assert all(node is not template.get(k) for k, node in nodes.items())
        assert nodes.shared() == 0
    finally:
        await sim.stop()


async def test_a_copied_space_is_asyncua_own_standard_space() -> None:
    """Every node, attribute value and reference of a server started the plain
    way (asyncua fills the standard address space itself) is in the copy."""
    plain = Server()
    await plain.iserver.load_standard_address_space()
    want = plain.iserver.aspace._nodes
    got = await standard_nodes()
    assert got.keys() == want.keys() and len(got) > 5000
    for nodeid, node in want.items():
        mine = got[nodeid]
        assert mine.attributes.keys() == node.attributes.keys(), nodeid
        for attr, av in node.attributes.items():
            assert mine.attributes[attr].value == av.value, (nodeid, attr)
        assert mine.references == node.references, nodeid


async def test_servers_do_not_share_what_they_change() -> None:
    """A namespace registered, a value written and a reference added on one
    simulated server are not on the next one (each has its own copy)."""
    one = OpcUaSimController()
    await one.start()
    try:
        server = one._require()
        await server.register_namespace("urn:compd:test:one")
        level = server.get_node(_node("Server_ServiceLevel"))
        await level.write_value(ua.Variant(7, ua.VariantType.Byte))
        objects = server.get_node(_node("ObjectsFolder"))
        await objects.add_folder(2, "OnlyOnOne")
        two = OpcUaSimController()
        await two.start()
        try:
            other = two._require()
            namespaces = await other.get_namespace_array()
            assert namespaces[-1] == NAMESPACE and "urn:compd:test:one" not in namespaces
            level_two = other.get_node(_node("Server_ServiceLevel"))
            assert await level_two.read_value() == 255
            names = [(await n.read_browse_name()).Name
                     for n in await other.get_node(_node("ObjectsFolder"))
                     .get_children()]
            assert "Machine" in names and "OnlyOnOne" not in names
        finally:
            await two.stop()
        assert "urn:compd:test:one" in await server.get_namespace_array()
    finally:
        await one.stop()


def _template_state() -> dict[ua.NodeId, tuple[object, ...]]:
    """The template as values (reprs, so a list changed in place shows)."""
    template = opcua_space._template
    assert template is not None
    return {nodeid: (id(node), repr(node.references), node.call,
                     {attr: (repr(av.value), av.value_callback, av.value_setter,
                             len(av.datachange_callbacks))
                      for attr, av in node.attributes.items()})
            for nodeid, node in template.items()}


async def test_what_the_face_does_to_its_server_leaves_the_template_as_built() -> None:
    """What the daemon's face does to its server (its start, a namespace, an
    enumeration data type, an object renamed and written, then deleted with the
    references to it) changes this server's copies only: the template, what the
    next server starts from, is as it was built."""
    from asyncua.common.structures104 import new_enum

    await standard_nodes()  # the template built
    before = _template_state()
    server = Server(iserver=opcua_space.CopiedSpaceInternalServer())
    await server.init()
    idx = await server.register_namespace("urn:compd:test:face")
    enum = await new_enum(server, idx, "TemplateTestState", ["a", "b"])
    await server.load_data_type_definitions()
    obj = await server.nodes.objects.add_object(
        ua.NodeId(ua.String("face.Machine"), ua.Int16(idx)), f"{idx}:face")
    var = await obj.add_variable(idx, "State", ua.Variant(0, ua.VariantType.Int32),
                                 datatype=enum.nodeid)
    await var.write_value(ua.Variant(1, ua.VariantType.Int32))
    await obj.write_attribute(AttributeIds.DisplayName, ua.DataValue(
        ua.Variant(ua.LocalizedText("renamed"), ua.VariantType.LocalizedText)))
    await server.write_attribute_value(_node("Server_ServiceLevel"),
                                       ua.DataValue(ua.Variant(9, ua.VariantType.Byte)))
    await server.delete_nodes([obj], recursive=True)
    assert _template_state() == before
