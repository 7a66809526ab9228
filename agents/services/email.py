"""E-mail send / fetch against a local Maildir per user (work_dir/mail/<user>); no SMTP needed."""
from __future__ import annotations

import email.message
import email.utils
import mailbox
import re
import threading

from ontology.registry import Done
from ontology.services.email import EmailFetch, EmailList, EmailMessage, EmailSend
from ontology.errors import ErrorCode

from .context import ServiceContext
from .errors import ServiceError

_lock = threading.Lock()
USER_RE = re.compile(r"^[A-Za-z0-9_.-]+$")


def maildir(ctx: ServiceContext, user: str) -> mailbox.Maildir:
    root = ctx.state.work_dir / "mail"
    root.mkdir(parents=True, exist_ok=True)
    return mailbox.Maildir(root / user, create=True)


def email_send(req: EmailSend, ctx: ServiceContext) -> Done:
    users = [r.split("@", 1)[0] for r in req.recipients]
    bad = [r for r, u in zip(req.recipients, users) if not USER_RE.match(u)]
    if bad:
        raise ServiceError(f"invalid recipient(s): {', '.join(bad)}", ErrorCode.BAD_RECIPIENT)
    msg = email.message.EmailMessage()
    msg["From"] = ctx.user
    msg["To"] = ", ".join(req.recipients)
    msg["Subject"] = req.subject
    msg["Date"] = email.utils.formatdate(localtime=True)
    msg.set_content(req.body)
    with _lock:
        for u in users:
            maildir(ctx, u).add(mailbox.MaildirMessage(msg))
    return Done()


def email_fetch(req: EmailFetch, ctx: ServiceContext) -> EmailList:
    out = []
    with _lock:
        box = maildir(ctx, ctx.user)
        for key in sorted(box.keys(), key=lambda k: box.get_message(k).get_date()):
            m = box.get_message(key)
            unread = "S" not in m.get_flags()
            if req.unread_only and not unread:
                continue
            body = m.get_payload(decode=True) or b""
            out.append(EmailMessage(id=key, sender=m["From"] or "", recipients=[r.strip() for r in (m["To"] or "").split(",") if r.strip()],
                                    subject=m["Subject"] or "", body=body.decode(m.get_content_charset() or "utf-8", "replace").strip(),
                                    date=m["Date"] or "", unread=unread))
            if req.mark_read and unread:
                m.add_flag("S")
                m.set_subdir("cur")
                box[key] = m
            if len(out) >= req.max_messages:
                break
    return EmailList(messages=out)
