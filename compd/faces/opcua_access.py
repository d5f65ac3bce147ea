"""Who may do what on compd's OPC UA face: the security policies by config name, the
user manager (the operator with its password, anonymous readers when allowed; failed
logins counted by the guard) and the permission rules (reading, browsing and
subscribing for every session, a method call only for the operator, nothing else)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

from asyncua import ua
from asyncua.crypto.permission_rules import PermissionRuleset, User, UserRole
from asyncua.server.user_managers import UserManager
from asyncua.ua.object_ids import ObjectIds

if TYPE_CHECKING:
    from asyncua.server.internal_server import InternalServer

    from compd.faces.opcua_limits import Guard

POLICIES = {
    "Basic256Sha256": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    "Aes128_Sha256_RsaOaep": ua.SecurityPolicyType.Aes128Sha256RsaOaep_SignAndEncrypt,
    "Aes256_Sha256_RsaPss": ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt,
    "None": ua.SecurityPolicyType.NoSecurity,
}
#: requests any client may make once its session is up (reading, browsing, subscribing)
_READ_REQUESTS = frozenset(ua.NodeId(ua.Int32(i)) for i in (
    ObjectIds.CreateSessionRequest_Encoding_DefaultBinary,
    ObjectIds.CloseSessionRequest_Encoding_DefaultBinary,
    ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary,
    ObjectIds.ReadRequest_Encoding_DefaultBinary,
    ObjectIds.BrowseRequest_Encoding_DefaultBinary,
    ObjectIds.BrowseNextRequest_Encoding_DefaultBinary,
    ObjectIds.GetEndpointsRequest_Encoding_DefaultBinary,
    ObjectIds.FindServersRequest_Encoding_DefaultBinary,
    ObjectIds.TranslateBrowsePathsToNodeIdsRequest_Encoding_DefaultBinary,
    ObjectIds.RegisterNodesRequest_Encoding_DefaultBinary,
    ObjectIds.UnregisterNodesRequest_Encoding_DefaultBinary,
    ObjectIds.CreateSubscriptionRequest_Encoding_DefaultBinary,
    ObjectIds.ModifySubscriptionRequest_Encoding_DefaultBinary,
    ObjectIds.DeleteSubscriptionsRequest_Encoding_DefaultBinary,
    ObjectIds.SetPublishingModeRequest_Encoding_DefaultBinary,
    ObjectIds.CreateMonitoredItemsRequest_Encoding_DefaultBinary,
    ObjectIds.ModifyMonitoredItemsRequest_Encoding_DefaultBinary,
    ObjectIds.DeleteMonitoredItemsRequest_Encoding_DefaultBinary,
    ObjectIds.SetMonitoringModeRequest_Encoding_DefaultBinary,
    ObjectIds.PublishRequest_Encoding_DefaultBinary,
    ObjectIds.RepublishRequest_Encoding_DefaultBinary,
    ObjectIds.TransferSubscriptionsRequest_Encoding_DefaultBinary,
))
_CALL_REQUEST = ua.NodeId(ua.Int32(ObjectIds.CallRequest_Encoding_DefaultBinary))


class Users(UserManager):
    """The operator with its password; anonymous readers when allowed. Failed
    logins and sessions over the limit go to the guard (it knows the peer)."""

    def __init__(self, operator: str | None, password: str | None, anonymous: bool,
                 guard: Guard) -> None:
        self.operator, self._password, self.anonymous = operator, password, anonymous
        self.guard = guard

    def get_user(self, iserver: InternalServer, username: str | None = None,
                 password: str | None = None, certificate: Any = None) -> User | None:
        user: User | None = None
        if username is None:
            user = User(role=UserRole.Anonymous) if self.anonymous else None
        elif self.operator is not None and username == self.operator \
                and password is not None and password == self._password:
            user = User(role=UserRole.User, name=username)
        if user is None:
            self.guard.login_failed("anonymous" if username is None else username)
        else:  # BadTooManySessions over the limit (the anonymous share, for anonymous)
            self.guard.login_ok(username or "anonymous", anonymous=username is None)
        return user


class CallGate(Protocol):
    """Who may call methods, and where a call's check is noted (the shared server)."""

    operator: str | None

    def note_call(self, user: Any, allowed: bool) -> None: ...


class ReadOnlyRules(PermissionRuleset):
    """Reading for every session; a Call only for the operator; nothing else."""

    def __init__(self, shared: CallGate) -> None:
        self.shared = shared

    def check_validity(self, user: Any, action_type_id: Any, body: Any) -> bool:
        if action_type_id in _READ_REQUESTS:
            return True
        if action_type_id == _CALL_REQUEST:
            allowed = user is not None and self.shared.operator is not None \
                and user.name == self.shared.operator
            self.shared.note_call(user, allowed)
            return allowed
        return False

